"""Send a rejected message to the dead-letter exchange, with why, and keep its origin."""

from __future__ import annotations

from datetime import datetime, timezone

import aio_pika
from aio_pika.abc import AbstractExchange, AbstractIncomingMessage

from schemas.routing import DETAIL_HEADER, REASON_HEADER
from workers.validation import Rejected


async def dead_letter(
    exchange: AbstractExchange, message: AbstractIncomingMessage, rejection: Rejected
) -> None:
    """Publish (confirmed) a copy with reason headers; the caller acks the original after."""
    headers = dict(message.headers or {})
    headers.update(
        {
            REASON_HEADER: rejection.reason.value,
            DETAIL_HEADER: rejection.detail[:4000],
            "x-original-exchange": message.exchange or "",
            "x-original-routing-key": message.routing_key or "",
            "x-original-user-id": message.user_id or "",
            "x-rejected-at": datetime.now(timezone.utc).isoformat(),
        }
    )
    copy = aio_pika.Message(
        message.body,
        headers=headers,
        content_type=message.content_type,
        message_id=message.message_id,
        timestamp=message.timestamp,
        type=message.type,
        delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
    )
    await exchange.publish(copy, routing_key=message.routing_key or "", mandatory=True)
