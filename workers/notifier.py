"""Fan a notification out for each newly stored event that robots or operators follow.

The service publishes once to ``fleetbus.notify``; the broker copies it into every inbox bound
to its topic (wardens to ``notify.hazard``, operators to ``notify.#``).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timezone

import aio_pika
from aio_pika.abc import AbstractExchange

from schemas.notifications import Notification
from schemas.routing import EventType, Topic, notification_routing_key
from workers.validation import Accepted

#: Event types announced as soon as they are stored; hazards go through the coordinator's gate.
TOPICS: dict[EventType, Topic] = {}


def needs_notification(item: Accepted) -> bool:
    return item.event.type in TOPICS


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


async def notify(exchange: AbstractExchange, items: Sequence[Accepted], service_user: str) -> None:
    """Publish the notifications of ``items`` in order and wait for all their confirms."""
    now = datetime.now(timezone.utc)
    for item in items:
        topic = TOPICS[item.event.type]
        note = Notification(
            topic=topic, event=item.event, received_at=item.record.received_at, notified_at=now
        )
        await publish_notification(exchange, note, service_user)
