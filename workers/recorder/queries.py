"""Questions asked of the recording, as plain functions over the stores.

The command line and the HTTP API both call these; neither talks to a database itself.

- :func:`find`: field conditions and a time window on any type (``name=grab``, ``frame=/a``);
- :func:`timeline`: what a robot and the service exchanged in a window, every type in time order;
- :func:`evaluate`: successes, failures and durations per behaviour, computed in the database;
- :func:`trace`: where a message came from, what the service made of it and what it caused.
"""

from __future__ import annotations

import base64
import heapq
import json
from collections.abc import AsyncIterator, Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta
from typing import Any, TypeVar

from fleetbus.broker.routes import Route, RouteMap
from fleetbus.schemas.ros import MESSAGE_FIELDS, ROS_SCHEMA_TYPE, ROS_TF_TYPE, ROS_TYPE
from fleetbus.schemas.routing import (
    ANNOUNCED_TO_HEADER,
    EXPRESS_QUEUE,
    RECORDER_QUEUE,
    EventType,
    Topic,
    inbox_queue,
    shard_of_queue,
)
from fleetbus.schemas.topics import topic_matches
from fleetbus.workers.recorder.capture import COPIES, DEAD_LETTER, NOTIFICATION, refusal
from fleetbus.workers.store.base import EventQuery, EventRecord, EventStore
from fleetbus.workers.store.recordings import (
    Condition,
    Op,
    OutcomeFields,
    OutcomeStats,
    RecordedMessage,
    RecordingError,
    RecordingStore,
    RecordQuery,
    Scalar,
    check_type_name,
)

T = TypeVar("T")

#: How many records a search (a type's, with conditions) and a robot's timeline return unless told,
#: and the most either returns: one rule for the command line, the HTTP API and the console.
SEARCH_LIMIT = 100
TIMELINE_LIMIT = 1000
LIMIT_MAX = 10_000

#: The top-level fields of a fleetbus event envelope; any other field of an event type is its body's.
ENVELOPE_FIELDS = frozenset(
    {"message_id", "robot_id", "epoch", "seq", "sent_at", "schema_version", "type", "body"}
)
EVENT_TYPES = frozenset(t.value for t in EventType)
#: Operators of a written condition, longest first so that ``<=`` is not read as ``<``.
WRITTEN_OPS = (Op.NE, Op.LE, Op.GE, Op.EQ, Op.LT, Op.GT, Op.CONTAINS)
BEHAVIOUR = EventType.BEHAVIOUR.value
#: Records read at once per type when a window is streamed (replay).
PAGE = 500


def resolve_path(type: str, path: str) -> str:
    """A field of an event type's body may be named alone: ``name`` is ``body.name`` for behaviours;
    a ROS message's field likewise: ``data`` is ``fields.data`` (its ``topic`` is its own)."""
    first = path.split(".", 1)[0]
    if type == ROS_TYPE:
        return path if first in MESSAGE_FIELDS else f"fields.{path}"
    if type in EVENT_TYPES and first not in ENVELOPE_FIELDS:
        return f"body.{path}"
    return path


def parse_value(text: str) -> Scalar:
    """A JSON scalar (``false``, ``3``, ``2.5``, ``null``, ``"3"``), else the text itself."""
    try:
        value = json.loads(text)
    except ValueError:
        return text
    if isinstance(value, (dict, list)):
        raise RecordingError(f"{text!r}: compare fields with a number, a string, true, false or null")
    return value  # type: ignore[no-any-return]


def parse_condition(text: str, type: str) -> Condition:
    """``FIELD OP VALUE`` with OP one of ``= != < <= > >= ~``, e.g. ``success=false``, ``frame=/a``."""
    for op in WRITTEN_OPS:
        path, found, value = text.partition(op.value)
        if found:
            path = path.strip()
            if not path:
                break
            return Condition(resolve_path(type, path), op, parse_value(value.strip()))
    raise RecordingError(f"condition {text!r}: write FIELD=VALUE (or != < <= > >= ~), e.g. success=false")


async def find(
    store: RecordingStore,
    type: str,
    conditions: Sequence[Condition] = (),
    *,
    robot_id: str | None = None,
    since: datetime | None = None,
    until: datetime | None = None,
    limit: int | None = None,
    newest_first: bool = False,
    mission_id: str | None = None,
    index: bool = True,
) -> list[RecordedMessage]:
    """Records of ``type`` meeting every condition, in the window; with ``index``, the fields the
    conditions name get an index first (made once, kept for every later query and insert)."""
    check_type_name(type)
    paths = sorted({condition.path for condition in conditions})
    if index and paths and type in await store.recorded_types():
        await store.ensure_field_index(type, paths)
    query = RecordQuery(
        type,
        tuple(conditions),
        robot_id=robot_id,
        since=since,
        until=until,
        limit=limit,
        newest_first=newest_first,
        mission_id=mission_id,
    )
    return await store.find_recorded(query)


def in_time_order(streams: Iterable[Iterable[T]], record: Callable[[T], RecordedMessage]) -> list[T]:
    """Streams each in recording order, merged into one."""
    return list(heapq.merge(*streams, key=lambda item: (record(item).recorded_at, record(item).key)))


async def recorded_between(
    store: RecordingStore,
    since: datetime | None,
    until: datetime | None,
    *,
    types: Sequence[str] = (),
    robot_id: str | None = None,
    conditions: Sequence[Condition] = (),
    page: int = PAGE,
) -> AsyncIterator[RecordedMessage]:
    """Records of the window in recording order, of ``types`` (default: all but the copies, dead
    letters and transforms); ``conditions`` need exactly one type, whose fields they name.

    Streamed: each type is read ``page`` records at a time and the pages merged as they are
    read, so a window of any size takes the memory of one page per type.
    """
    if conditions and len(types) != 1:
        raise RecordingError("field conditions apply to one type: name exactly one")
    chosen = list(types) or [t for t in await store.recorded_types() if t not in COPIES]
    queries = [
        RecordQuery(
            check_type_name(t), tuple(conditions), robot_id=robot_id, since=since, until=until, limit=page
        )
        for t in chosen
    ]
    streams = [_paged(store, query) for query in queries]
    heads: list[tuple[datetime, str, int, RecordedMessage]] = []
    for index, stream in enumerate(streams):
        await _push(heads, index, stream)
    while heads:
        _, _, index, record = heapq.heappop(heads)
        yield record
        await _push(heads, index, streams[index])


async def _paged(store: RecordingStore, query: RecordQuery) -> AsyncIterator[RecordedMessage]:
    """One type's records of the window, oldest first, a page at a time (keyset: after the last)."""
    while True:
        found = await store.find_recorded(query)
        for record in found:
            yield record
        if query.limit is None or len(found) < query.limit:
            return
        query = replace(query, after=(found[-1].recorded_at, found[-1].key))


async def _push(
    heads: list[tuple[datetime, str, int, RecordedMessage]],
    index: int,
    stream: AsyncIterator[RecordedMessage],
) -> None:
    record = await anext(stream, None)
    if record is not None:
        heapq.heappush(heads, (record.recorded_at, record.key, index, record))


@dataclass(frozen=True)
class TimelineEntry:
    record: RecordedMessage
    sent: bool
    """True for what the robot sent (and the service refused), False for what it was sent."""


@dataclass(frozen=True)
class Timeline:
    robot_id: str
    entries: list[TimelineEntry]
    truncated: bool
    """More happened in the window than the limit shows."""


async def timeline(
    store: RecordingStore,
    robot_id: str,
    since: datetime | None,
    until: datetime | None,
    *,
    inbound: Sequence[str] = (),
    limit: int = 1000,
) -> Timeline:
    """Every type merged in recording order: what ``robot_id`` published (events, requests, and the
    dead letters of what the service refused) and the notifications whose routing keys match the
    ``inbound`` patterns (the bindings of the robot's inbox) or that were delivered to its inbox by
    name (a hazard announcement, whose recorded copy names the wardens that took it)."""
    streams: list[Iterable[TimelineEntry]] = []
    types = await store.recorded_types()
    for type in types:
        if type in (ROS_TF_TYPE, ROS_SCHEMA_TYPE):
            continue  # what the ROS messages the timeline shows bring with them
        sent = await store.find_recorded(
            RecordQuery(type, robot_id=robot_id, since=since, until=until, limit=limit + 1)
        )
        streams.append(TimelineEntry(record, True) for record in sent)
    if NOTIFICATION in types:
        notes = await store.find_recorded(RecordQuery(NOTIFICATION, since=since, until=until))
        received = [
            n
            for n in notes
            if robot_id in announced_to(n)
            or any(topic_matches(pattern, n.routing_key) for pattern in inbound)
        ]
        streams.append(TimelineEntry(record, False) for record in received[: limit + 1])
    merged = in_time_order(streams, lambda entry: entry.record)
    return Timeline(robot_id, merged[:limit], len(merged) > limit)


async def evaluate(
    store: RecordingStore,
    since: datetime | None = None,
    until: datetime | None = None,
    *,
    robot_id: str | None = None,
    type: str = BEHAVIOUR,
    fields: OutcomeFields = OutcomeFields(),  # noqa: B008  (frozen)
) -> list[OutcomeStats]:
    """Per behaviour (or per name in ``type``): successes, failures, mean and deviation of duration."""
    check_type_name(type)
    if type in await store.recorded_types():
        await store.ensure_field_index(type, [fields.name])
    return await store.outcome_stats(type, fields, since, until, robot_id)


@dataclass
class Trace:
    message_id: str
    records: list[RecordedMessage]
    """Every recorded copy: the message as published, and its dead letter if the service refused it."""
    stored: EventRecord | None = None
    """The event log's copy, when the service accepted it (with the mission it was recorded under)."""
    caused: list[RecordedMessage] = field(default_factory=list)
    """The notifications the service sent because of it."""
    routes: dict[str, list[Route]] = field(default_factory=dict)
    """By record key: the queues the broker routes such a message to now, and their consumers."""

    @property
    def origin(self) -> RecordedMessage | None:
        return next(
            (r for r in self.records if r.type != DEAD_LETTER), self.records[0] if self.records else None
        )

    @property
    def refused(self) -> RecordedMessage | None:
        return next((r for r in self.records if r.type == DEAD_LETTER), None)

    def outcome(self, record: RecordedMessage, queue: str, clock: Callable[[datetime], str]) -> str:
        """What is known of what ``queue``'s consumer did with ``record`` ("" when nothing is):
        the recorder recorded it; an ingest queue's worker stored it, or refused it."""
        if queue == RECORDER_QUEUE:
            return f"recorded at {clock(record.recorded_at)}"
        if queue == EXPRESS_QUEUE or shard_of_queue(queue) is not None:
            if self.stored is not None:
                stored = self.stored
                return f"stored at {clock(stored.received_at)} as epoch {stored.epoch} seq {stored.seq}"
            refused = self.refused
            if refused is not None:
                reason, detail = refusal(refused) or ("?", "")
                return f"refused: {reason}: {detail}"
        return ""


async def trace(
    store: RecordingStore,
    message_id: str,
    *,
    events: EventStore | None = None,
    route_map: RouteMap | None = None,
) -> Trace:
    """All that is known of ``message_id``; empty ``records`` when it was never recorded."""
    types = await store.recorded_types()
    records: list[RecordedMessage] = []
    for type in types:
        records.extend(await store.find_recorded(RecordQuery(type, message_id=message_id)))
    records.sort(key=lambda r: (r.recorded_at, r.key))
    result = Trace(message_id, records)
    if NOTIFICATION in types:
        for topic in Topic:
            query = RecordQuery(NOTIFICATION, message_id=f"{message_id}:{topic.value}")
            result.caused.extend(await store.find_recorded(query))
    origin = result.origin
    if events is not None and origin is not None:
        result.stored = await stored_copy(events, origin)
    if route_map is not None:
        for record in [*records, *result.caused]:
            if record.type != DEAD_LETTER:
                result.routes[record.key] = route_map.routes(record.exchange, record.routing_key) + [
                    route
                    for robot in announced_to(record)
                    for route in route_map.routes("", inbox_queue(robot))
                ]
    return result


def announced_to(record: RecordedMessage) -> list[str]:
    """The wardens a recorded hazard announcement was delivered to by name (its copy's header)."""
    headers = record.properties.get("headers") or {}
    robots = headers.get(ANNOUNCED_TO_HEADER) or []
    return [str(robot) for robot in robots] if isinstance(robots, list) else []


async def stored_copy(events: EventStore, record: RecordedMessage) -> EventRecord | None:
    """The event log's record of a recorded event (found by robot, type and the exact send time)."""
    if record.type not in EVENT_TYPES or record.sent_at is None or record.robot_id is None:
        return None
    query = EventQuery(
        type=record.type,
        robot_id=record.robot_id,
        since=record.sent_at,
        until=record.sent_at + timedelta(microseconds=1),
    )
    return next((e for e in await events.find_events(query) if e.message_id == record.message_id), None)


def record_view(record: RecordedMessage) -> dict[str, Any]:
    """A record as JSON, shaped like the reference's documents: the body's own fields as received,
    and what the recorder knows under ``__recorded`` (a body that is not an object is ``__body``,
    one kept raw is ``__raw``, base64)."""
    recorded: dict[str, Any] = {
        "type": record.type,
        "at": record.recorded_at.isoformat(),
        "key": record.key,
        "known": record.known,
        "user_id": record.user_id,
        "robot_id": record.robot_id,
        "exchange": record.exchange,
        "routing_key": record.routing_key,
        "message_id": record.message_id,
        "mission_id": record.mission_id,
        "size": record.size,
    }
    if record.problem:
        recorded["problem"] = record.problem
    if record.properties.get("headers"):
        recorded["headers"] = record.properties["headers"]
    if isinstance(record.document, dict):
        view = dict(record.document)
    elif record.raw is not None:
        view = {"__raw": base64.b64encode(record.raw).decode()}
    else:
        view = {"__body": record.document}
    view["__recorded"] = recorded
    return view
