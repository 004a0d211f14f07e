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


class RequestNotSent(BrokerUnavailable):
    """The call's connection or channel was found dead before its request was published: the
    request never left, so the call may be made again on a new one (the client does so, once)."""


class RpcChannel:
    def __init__(self, connection: BlockingConnection, robot_id: str) -> None:
        self._connection = connection
        self._robot_id = robot_id
        self._channel: BlockingChannel = connection.channel()
        self._replies: dict[str, bytes] = {}
        self._waiting: set[str] = set()
        """The calls waiting for their reply: a late one (after its call's timeout) is dropped."""
        self._channel.basic_consume(REPLY_TO, self._on_reply, auto_ack=True)

    @property
    def is_open(self) -> bool:
        return self._connection.is_open and self._channel.is_open

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
            self._publish(method, params, properties)
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

    def _publish(self, method: str, params: dict[str, Any], properties: pika.BasicProperties) -> None:
        """Publish a request; :class:`RequestNotSent` when the connection or the channel is found
        dead first. Between calls nothing runs pika on this connection (no heartbeats): a broker
        that restarted, or closed the connection of an idle robot, or closed this channel (a 404),
        is only learnt of here, by reading what it sent meanwhile, before anything is written."""
        try:
            self._connection.process_data_events(0)
        except pika.exceptions.AMQPError as error:
            raise RequestNotSent(f"connection lost before {method!r} was sent: {error!r}") from error
        if not self.is_open:
            raise RequestNotSent(f"the service channel was closed before {method!r} was sent")
        try:
            self._channel.basic_publish(
                requests_exchange(self._robot_id),
                request_routing_key(self._robot_id, method),
                json.dumps(params).encode(),
                properties,
            )
        except (pika.exceptions.ChannelWrongStateError, pika.exceptions.ConnectionWrongStateError) as error:
            # raised before pika queued a byte of the request
            raise RequestNotSent(f"connection lost before {method!r} was sent: {error!r}") from error
        except pika.exceptions.AMQPError as error:  # while writing: it may have reached the broker
            raise BrokerUnavailable(f"connection lost during {method!r}: {error!r}") from error
