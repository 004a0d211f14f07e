"""Publish notifications to robots and operators.

The service publishes once to ``fleetbus.notify``; the broker copies it into every inbox bound
to its topic (wardens to ``notify.hazard``, operators to ``notify.#``).
"""

from __future__ import annotations

import aio_pika
from aio_pika.abc import AbstractExchange

from schemas.notifications import Notification
from schemas.routing import notification_routing_key


async def publish_notification(exchange: AbstractExchange, note: Notification, service_user: str) -> None:
    """Publish one notification (persistent, confirmed) to everyone subscribed to its topic."""
    message = aio_pika.Message(
        note.model_dump_json().encode(),
        content_type="application/json",
        delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
        message_id=f"{note.event.message_id}:{note.topic.value}",
        user_id=service_user,
        type=note.topic.value,
    )
    await exchange.publish(message, routing_key=notification_routing_key(note.topic), mandatory=False)
