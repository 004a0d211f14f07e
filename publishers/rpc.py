"""Calling the service from a robot: request/reply over AMQP with direct reply-to.

A call waits at most ``timeout`` seconds; the request carries the same expiration, so a service
that comes back later never answers a question nobody is waiting for.
"""

from __future__ import annotations

import json
import time
import uuid
from typing import Any

import pika
import pika.exceptions
from pika.adapters.blocking_connection import BlockingChannel, BlockingConnection

from fleetbus.publishers.errors import BrokerUnavailable, PublisherError
from fleetbus.schemas.routing import request_routing_key, requests_exchange

REPLY_TO = "amq.rabbitmq.reply-to"


class ServiceTimeout(PublisherError):
    """No reply within the timeout: the service is down, overloaded or unreachable."""


class ServiceRefused(PublisherError):
    """The service refused the request; the message is its reason (the caller's to fix)."""


class ServiceFailed(PublisherError):
    """The service failed on the request (a bug of its own, logged there under the reference the
    message gives): not the request's fault; the same call may work once the service is fixed."""


class RpcChannel:
    def __init__(self, connection: BlockingConnection, robot_id: str) -> None:
        self._connection = connection
        self._robot_id = robot_id
        self._channel: BlockingChannel = connection.channel()
        self._replies: dict[str, bytes] = {}
        self._waiting: set[str] = set()
        """The calls waiting for their reply: a late one (after its call's timeout) is dropped."""
        self._channel.basic_consume(REPLY_TO, self._on_reply, auto_ack=True)

    def _on_reply(
        self, _channel: object, _method: object, properties: pika.BasicProperties, body: bytes
    ) -> None:
        if properties.correlation_id in self._waiting:
            self._replies[properties.correlation_id] = body

    def call(self, method: str, params: dict[str, Any], timeout: float) -> Any:
        correlation_id = uuid.uuid4().hex
        properties = pika.BasicProperties(
            content_type="application/json",
            reply_to=REPLY_TO,
            correlation_id=correlation_id,
            user_id=self._robot_id,
            expiration=str(max(1, int(timeout * 1000))),
        )
        self._waiting.add(correlation_id)
        try:
            self._channel.basic_publish(
                requests_exchange(self._robot_id),
                request_routing_key(self._robot_id, method),
                json.dumps(params).encode(),
                properties,
            )
            deadline = time.monotonic() + timeout
            while correlation_id not in self._replies:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise ServiceTimeout(
                        f"no reply from the fleetbus service {method!r} within {timeout:g} s "
                        "(is `fleetbus worker` running?)"
                    )
                self._connection.process_data_events(time_limit=min(0.05, remaining))
        except pika.exceptions.AMQPError as error:
            raise BrokerUnavailable(f"connection lost during {method!r}: {error!r}") from error
        finally:
            self._waiting.discard(correlation_id)
        reply = json.loads(self._replies.pop(correlation_id))
        if not reply.get("ok") and reply.get("internal"):
            raise ServiceFailed(f"{method}: {reply.get('error', 'failed')}")
        if not reply.get("ok"):
            raise ServiceRefused(f"{method}: {reply.get('error', 'refused')}")
        return reply.get("result")
