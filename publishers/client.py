"""The robot-side client: synchronous, on pika, for robot code that is usually synchronous.

with RobotClient(url) as robot:                   # the URL's user is the robot's account
    robot.publish("hazard", {...})                # returns once the broker confirmed it
    robot.publish_many([("status", {...}), ...])  # pipelined confirms
    for note in robot.notifications(timeout=5):   # this robot's inbox
        ...
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from datetime import datetime
from pathlib import Path
from types import TracebackType
from typing import Any
from urllib.parse import unquote, urlsplit

import pika
import pika.exceptions
from pika.adapters.blocking_connection import BlockingChannel

from publishers.confirms import Outgoing, PipelinedConfirms
from publishers.errors import BrokerUnavailable
from publishers.maps import FetchedMap, fetch_map, map_events
from publishers.rpc import RpcChannel
from publishers.sequence import SequenceCounter
from schemas.bodies import MapMetadata
from schemas.envelope import Event, build_event, encode_event, validate_body
from schemas.identity import validate_name
from schemas.notifications import Notification
from schemas.routing import EventType, beacon_headers, event_routing_key, inbox_queue, publish_exchange

#: Largest batch written before waiting for its confirms; bounds memory and redelivery work.
PUBLISH_WINDOW = 1000


def robot_state_path(state_dir: Path, robot_id: str) -> Path:
    return state_dir / robot_id / "state.json"


def to_outgoing(event: Event) -> Outgoing:
    properties = pika.BasicProperties(
        content_type="application/json",
        delivery_mode=pika.DeliveryMode.Persistent,
        message_id=str(event.message_id),
        user_id=event.robot_id,  # checked by the broker against the login
        timestamp=int(event.sent_at.timestamp()),
        type=event.type.value,
        app_id="fleetbus-robot",
        # beacons pass the robot's beacon exchange only with these headers
        headers=beacon_headers(event.robot_id) if event.type is EventType.BEACON else None,
    )
    return Outgoing(
        publish_exchange(event.robot_id, event.type),
        event_routing_key(event.robot_id, event.type),
        encode_event(event),
        properties,
    )


class RobotClient:
    def __init__(
        self,
        amqp_url: str,
        *,
        state_dir: Path,
        connect_timeout: float = 30.0,
        confirm_timeout: float = 30.0,
    ) -> None:
        self.robot_id = validate_name(unquote(urlsplit(amqp_url).username or ""))
        self._parameters = pika.URLParameters(amqp_url)
        self._parameters.heartbeat = 30
        self._parameters.connection_attempts = 1
        self._connect_timeout = connect_timeout
        self._confirm_timeout = confirm_timeout
        self._sequence = SequenceCounter(robot_state_path(state_dir, self.robot_id))
        self._connection: pika.BlockingConnection | None = None
        self._confirms: PipelinedConfirms | None = None
        self._rpc: RpcChannel | None = None

    # connection
    def connect(self) -> None:
        """Connect, retrying with backoff until ``connect_timeout``; raise BrokerUnavailable then."""
        deadline = time.monotonic() + self._connect_timeout
        delay = 0.2
        self._rpc = None
        while True:
            try:
                self._connection = pika.BlockingConnection(self._parameters)
                break
            except (pika.exceptions.ProbableAuthenticationError, pika.exceptions.ProbableAccessDeniedError):
                raise
            except pika.exceptions.AMQPConnectionError as error:
                if time.monotonic() + delay > deadline:
                    raise BrokerUnavailable(
                        f"cannot reach the broker at {self._parameters.host}:{self._parameters.port} "
                        f"within {self._connect_timeout:.0f} s: {error!r}"
                    ) from error
                time.sleep(delay)  # backoff between connection attempts
                delay = min(delay * 2, 5.0)
        self._confirms = PipelinedConfirms(
            self._connection, self._connection.channel(), self._confirm_timeout
        )

    def _ready(self) -> PipelinedConfirms:
        if self._confirms is None or self._connection is None or not self._connection.is_open:
            self.connect()
        elif self._confirms._closed_reason is not None:  # refused earlier: start a clean channel
            self._confirms = PipelinedConfirms(
                self._connection, self._connection.channel(), self._confirm_timeout
            )
        assert self._confirms is not None
        return self._confirms

    def close(self) -> None:
        if self._connection is not None and self._connection.is_open:
            self._connection.close()
        self._connection = None
        self._confirms = None
        self._rpc = None
        self._sequence.close()

    def __enter__(self) -> RobotClient:
        self.connect()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # publishing
    def build(self, items: Sequence[tuple[EventType | str, Any]]) -> list[Event]:
        """Validate bodies, then give them consecutive sequence numbers (none wasted on bad input)."""
        bodies = [(event_type, validate_body(event_type, body)) for event_type, body in items]
        first = self._sequence.reserve(len(bodies)) if bodies else 0
        return [build_event(t, self.robot_id, first + i, body) for i, (t, body) in enumerate(bodies)]

    def publish(self, event_type: EventType | str, body: Any) -> Event:
        return self.publish_many([(event_type, body)])[0]

    def publish_many(self, items: Iterable[tuple[EventType | str, Any]]) -> list[Event]:
        events = self.build(list(items))
        self.send(events)
        return events

    def send(self, events: Sequence[Event]) -> None:
        """Publish already built events (also a resend: same sequence number, no second record).

        A window whose confirms were lost with the connection is sent again on a new one, once:
        the store's (robot, seq) key makes the second copy harmless.
        """
        for start in range(0, len(events), PUBLISH_WINDOW):
            window = [to_outgoing(event) for event in events[start : start + PUBLISH_WINDOW]]
            try:
                self._ready().publish(window, self._confirm_timeout)
            except BrokerUnavailable:
                self.connect()
                self._ready().publish(window, self._confirm_timeout)

    # services
    def call(self, method: str, timeout: float = 5.0, **params: Any) -> Any:
        """Call a fleetbus service; raise ServiceTimeout when no reply comes within ``timeout``."""
        if self._rpc is None:
            if self._connection is None or not self._connection.is_open:
                self.connect()
            assert self._connection is not None
            self._rpc = RpcChannel(self._connection, self.robot_id)
        return self._rpc.call(method, params, timeout)

    def hazard(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("hazard.get", timeout, hazard_id=hazard_id)

    def open_hazards(self, timeout: float = 5.0) -> list[dict[str, Any]]:
        return self.call("hazard.open", timeout)

    def claim_hazard(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("hazard.claim", timeout, hazard_id=hazard_id)

    def release_hazard(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("hazard.release", timeout, hazard_id=hazard_id)

    def hazard_reached(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("hazard.reached", timeout, hazard_id=hazard_id)

    def hazard_cleared(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("hazard.cleared", timeout, hazard_id=hazard_id)

    def wardens(self, timeout: float = 5.0) -> list[dict[str, Any]]:
        return self.call("wardens", timeout)

    def publish_map(
        self, pgm: bytes, metadata: MapMetadata | dict[str, Any], created_at: datetime | None = None
    ) -> list[Event]:
        """Publish a map (PGM bytes and YAML fields); large images go as chunks, in one pipelined batch."""
        return self.publish_many(map_events(pgm, metadata, created_at))

    def fetch_map(self, version: int | None = None, timeout: float = 10.0) -> FetchedMap:
        """The latest (or a given) stored map, byte for byte."""
        return fetch_map(self, version, timeout)

    def beacon_info(self, beacon_id: str, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("beacon.info", timeout, beacon_id=beacon_id)

    def stranded(self, minutes: float = 10, timeout: float = 5.0) -> list[dict[str, Any]]:
        """Beacons heard in the last ``minutes``: where people are likely stranded."""
        return self.call("beacon.stranded", timeout, minutes=minutes)

    def beacon_goal(self, minutes: float = 10, timeout: float = 5.0) -> dict[str, Any] | None:
        """The guide's next beacon: the first heard of the recent ones not visited yet."""
        return self.call("beacon.goal", timeout, minutes=minutes)

    def beacon_visited(self, beacon_id: str, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("beacon.visited", timeout, beacon_id=beacon_id)

    # notifications
    def notifications(self, timeout: float | None = None, prefetch: int = 64) -> Iterator[Notification]:
        """This robot's notifications; stops after ``timeout`` seconds without one.

        Each notification is acked when the caller asks for the next one or stops iterating, so
        one that was being handled when the robot process died is delivered again.
        """
        channel = self._open_consumer_channel()
        channel.basic_qos(prefetch_count=prefetch)
        try:
            for method, _properties, body in channel.consume(
                inbox_queue(self.robot_id), inactivity_timeout=timeout
            ):
                if method is None:
                    return
                try:
                    yield Notification.model_validate_json(body)
                finally:  # the caller asked for the next one, or stopped iterating
                    if channel.is_open:
                        channel.basic_ack(method.delivery_tag)
        finally:
            if channel.is_open:
                channel.cancel()
                channel.close()

    def _open_consumer_channel(self) -> BlockingChannel:
        """A new channel, reconnecting first when the connection is gone (the broker restarted)."""
        if self._connection is not None and self._connection.is_open:
            try:
                return self._connection.channel()
            except pika.exceptions.AMQPError:
                pass  # the connection died under us; start a new one
        self.connect()
        assert self._connection is not None
        return self._connection.channel()

    def receive(self, count: int, timeout: float) -> list[Notification]:
        """Exactly ``count`` notifications, or fewer if ``timeout`` passes first."""
        received: list[Notification] = []
        deadline = time.monotonic() + timeout
        while len(received) < count and time.monotonic() < deadline:
            try:
                for note in self.notifications(timeout=max(0.1, deadline - time.monotonic())):
                    received.append(note)
                    if len(received) == count:
                        break
            except pika.exceptions.AMQPError:
                continue  # the broker went away; the unacked notification comes again after reconnecting
        return received
