"""Publish notifications to robots and operators.

Most notifications are published once to ``fleetbus.notify``; the broker copies each into every
inbox bound to its topic (guides and wardens to ``notify.map``, operators to ``notify.#``). Hazard
announcements are also delivered to each warden's inbox by name (:func:`deliver_to_inbox`): the
broker returns a copy that reached no queue, so the hazard service knows which wardens took it.
"""

from __future__ import annotations

from typing import Any

import aio_pika
import aiormq.abc
from aio_pika.abc import AbstractExchange

from fleetbus.publishers.confirms import SERVICE_CONFIRM_TIMEOUT_S
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import inbox_queue, notification_routing_key

#: The worker's bound on a notification's confirm: past it the publish raises, the event is not
#: acked, and the broker delivers it again (the store recognises it).
CONFIRM_TIMEOUT_S = SERVICE_CONFIRM_TIMEOUT_S


def _message(
    note: Notification, message_id: str, service_user: str, headers: dict[str, Any] | None = None
) -> aio_pika.Message:
    return aio_pika.Message(
        note.model_dump_json().encode(),
        content_type="application/json",
        delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
        message_id=message_id,
        user_id=service_user,
        type=note.topic.value,
        headers=headers,
    )


async def publish_notification(
    exchange: AbstractExchange, note: Notification, service_user: str, headers: dict[str, Any] | None = None
) -> None:
    """Publish one notification (persistent, confirmed) to everyone subscribed to its topic."""
    message = _message(note, f"{note.event.message_id}:{note.topic.value}", service_user, headers)
    await exchange.publish(
        message, routing_key=notification_routing_key(note.topic), mandatory=False, timeout=CONFIRM_TIMEOUT_S
    )


async def deliver_to_inbox(
    default_exchange: AbstractExchange, note: Notification, robot: str, service_user: str
) -> bool:
    """Put ``note`` in ``robot``'s inbox (persistent, confirmed); False when the broker returned it
    (the robot has no inbox). Needs a channel with publisher confirms; a nack raises."""
    # a message id of its own: aiormq matches a returned message to its publish by this id
    message_id = f"{note.event.message_id}:{note.topic.value}@{robot}"
    result = await default_exchange.publish(
        _message(note, message_id, service_user),
        routing_key=inbox_queue(robot),
        mandatory=True,
        timeout=CONFIRM_TIMEOUT_S,
    )
    if result is None:
        raise RuntimeError("delivering to an inbox needs a channel with publisher confirms")
    return not isinstance(result, aiormq.abc.DeliveredMessage)
