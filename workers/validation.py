"""Decide what a delivered message is: an event to store, or a rejection with a reason."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from aio_pika.abc import AbstractIncomingMessage

from fleetbus.schemas.envelope import Event, NotJSONError, SchemaError, content_digest, parse_event
from fleetbus.schemas.properties import content_type_problem, delivery_mode_problem
from fleetbus.schemas.rejections import RejectReason
from fleetbus.schemas.routing import SHOVELLED_HEADER, EventType, publish_exchange, split_event_routing_key
from fleetbus.workers.store.base import EventRecord


@dataclass(frozen=True)
class Accepted:
    event: Event
    record: EventRecord
    forwarded: bool = False
    """It came through a site's uplink (the shovel's ``x-shovelled`` header): a claim, believed
    only for the robots of the site (:mod:`fleetbus.workers.forwards`)."""
    stored_at: datetime | None = None
    """When the worker stored it (its ``record.received_at`` is when it took it from the broker);
    None before."""


@dataclass(frozen=True)
class Rejected:
    reason: RejectReason
    detail: str


def record_body(event: Event) -> dict[str, Any]:
    """The body as stored with the event; the bytes of chunks (a large map image, a ROS message's
    large byte array) are kept by the map store or the recording, not the event log."""
    if event.type in (EventType.MAP_CHUNK, EventType.ROS_CHUNK):
        return {**event.body.model_dump(mode="json", exclude={"data"}), "size": len(event.body.data)}
    if event.type is EventType.MAP and event.body.pgm is not None:
        return {**event.body.model_dump(mode="json", exclude={"pgm"}), "pgm_size": len(event.body.pgm)}
    return event.body.model_dump(mode="json")


def classify(
    message: AbstractIncomingMessage, max_bytes: int, received_at: datetime | None = None
) -> Accepted | Rejected:
    """``received_at``: when the worker took the message from the broker (default: now)."""
    received_at = received_at or datetime.now(timezone.utc)
    body = message.body
    if len(body) > max_bytes:
        return Rejected(RejectReason.TOO_LARGE, f"body is {len(body)} bytes; the limit is {max_bytes}")
    user_id = message.user_id
    if not user_id:
        return Rejected(
            RejectReason.NO_USER_ID, "the message has no user_id property, so its origin is unproven"
        )
    if problem := content_type_problem(message.content_type):
        return Rejected(RejectReason.CONTENT_TYPE, problem)
    if problem := delivery_mode_problem(message.delivery_mode):
        return Rejected(RejectReason.NOT_PERSISTENT, problem)
    routing_key = message.routing_key or ""
    try:
        key_robot, key_type = split_event_routing_key(routing_key)
    except ValueError as error:
        return Rejected(RejectReason.UNKNOWN_TYPE, str(error))
    if key_type not in EventType._value2member_map_:
        known = ", ".join(t.value for t in EventType)
        return Rejected(
            RejectReason.UNKNOWN_TYPE,
            f"routing key {routing_key!r} names unknown type {key_type!r}; known: {known}",
        )
    try:
        event = parse_event(body)
    except NotJSONError as error:
        return Rejected(RejectReason.NOT_JSON, str(error))
    except SchemaError as error:
        return Rejected(RejectReason.SCHEMA, str(error))
    if not (event.robot_id == key_robot == user_id) or event.type.value != key_type:
        return Rejected(
            RejectReason.IDENTITY_MISMATCH,
            f"user_id {user_id!r}, routing key {routing_key!r} and body robot_id {event.robot_id!r} "
            f"type {event.type.value!r} do not agree",
        )
    expected_exchange = publish_exchange(event.robot_id, event.type)
    if message.exchange != expected_exchange:
        return Rejected(
            RejectReason.WRONG_EXCHANGE,
            f"{event.type.value} events are published to {expected_exchange!r}, not {message.exchange!r}",
        )
    exchange, redelivered = message.exchange or "", bool(message.redelivered)
    record = event_record(event, received_at, user_id, exchange, routing_key, redelivered=redelivered)
    return Accepted(event, record, forwarded=SHOVELLED_HEADER in (message.headers or {}))


def event_record(
    event: Event,
    received_at: datetime,
    user_id: str,
    exchange: str,
    routing_key: str,
    *,
    redelivered: bool = False,
) -> EventRecord:
    """What is stored of a valid event: its envelope, its body as stored, and how it came."""
    return EventRecord(
        robot_id=event.robot_id,
        epoch=event.epoch,
        seq=event.seq,
        type=event.type.value,
        message_id=str(event.message_id),
        sent_at=event.sent_at,
        received_at=received_at,
        body=record_body(event),
        user_id=user_id,
        exchange=exchange,
        routing_key=routing_key,
        digest=content_digest(event.type, event.body),
        redelivered=redelivered,
    )
