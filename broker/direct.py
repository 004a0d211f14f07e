"""Put one message straight into a named queue, by the default exchange, as the administrator.

Persistent, confirmed and ``mandatory``: the broker says whether the queue took it. Only the
administrator and the service's own account may write to the default exchange (no robot can), so
what arrives this way in a warden's inbox or on the express lane came from the service side.
"""

from __future__ import annotations

import pika
import pika.exceptions

from fleetbus.publishers.confirms import SERVICE_CONFIRM_TIMEOUT_S, Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import CONNECTION_FAILED, BrokerUnavailable, PublishRefused, PublishTimeout
from fleetbus.publishers.tls import blocking_connection


class NoSuchQueue(RuntimeError):
    """The broker returned the message: no queue of that name."""


class NotTaken(RuntimeError):
    """The broker did not answer, or refused the message; the message says why."""


def put_in_queue(admin_url: str, queue: str, body: bytes, properties: pika.BasicProperties) -> None:
    """Publish ``body`` to ``queue`` and wait for the broker's confirm (blocking: run it on a thread)."""
    properties.delivery_mode = pika.DeliveryMode.Persistent.value
    try:
        connection = blocking_connection(admin_url)
    except (pika.exceptions.AMQPError, *CONNECTION_FAILED) as error:
        raise NotTaken(f"the broker does not answer ({error!r})") from error
    try:
        confirms = PipelinedConfirms(connection, connection.channel(), SERVICE_CONFIRM_TIMEOUT_S)
        outcome = confirms.send_one(Outgoing("", queue, body, properties))
    except (pika.exceptions.AMQPError, PublishRefused, BrokerUnavailable, PublishTimeout) as error:
        raise NotTaken(f"the broker refused it or did not confirm it ({error})") from error
    finally:
        if connection.is_open:
            connection.close()
    if outcome.returned:
        raise NoSuchQueue(f"there is no queue {queue} on this broker")
    if outcome.nacked:
        raise NotTaken(f"the broker nacked it (queue {queue} could not take it now)")
