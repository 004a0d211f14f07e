"""The recording's use cases, for the command line, the HTTP API and the console alike: what is
recorded, the messages of a type meeting conditions, a robot's timeline, a message's trace, the
behaviours' outcomes, the database's growth, a window streamed in recording order (replay,
export), and a ROS bag imported.

A query the recording refuses (a type or field that cannot be, a condition that does not parse, a
robot with nothing recorded) is refused as bad input (:class:`~fleetbus.api.services.errors.BadRequest`),
with the recording's words, as the HTTP API answers it (422)."""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

from fleetbus.api.services.errors import BadRequest
from fleetbus.broker.routes import RouteMap
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.ros import ROS_SCHEMA_TYPE
from fleetbus.workers.recorder.bag_import import ImportReport, Progress
from fleetbus.workers.recorder.bag_import import import_bag as import_bag_into
from fleetbus.workers.recorder.export_selection import Selection
from fleetbus.workers.recorder.growth import Growth, growth
from fleetbus.workers.recorder.queries import (
    BEHAVIOUR,
    Timeline,
    Trace,
    evaluate,
    find,
    parse_condition,
    recorded_between,
    resolve_path,
    timeline,
    trace,
)
from fleetbus.workers.recorder.ros_native import RosSchema, with_blobs
from fleetbus.workers.store.base import EventStore
from fleetbus.workers.store.recordings import (
    Condition,
    OutcomeFields,
    OutcomeStats,
    RecordedMessage,
    RecordingError,
    RecordingStore,
    RecordQuery,
    StorageSample,
    TypeSummary,
)

__all__ = [
    "Condition",
    "Growth",
    "ImportReport",
    "OutcomeStats",
    "RecordedMessage",
    "Recording",
    "Timeline",
    "Trace",
    "TypeSummary",
    "TypeView",
]


@dataclass(frozen=True)
class TypeView:
    """A recorded type: how much of it, from when to when, and the fields indexed for its queries."""

    summary: TypeSummary
    field_indexes: list[tuple[str, ...]]

    @property
    def name(self) -> str:
        return self.summary.type


@contextmanager
def _refused() -> Iterator[None]:
    """The recording's refusals as bad input, with its words."""
    try:
        yield
    except RecordingError as error:
        raise BadRequest(str(error)) from None


class Recording:
    def __init__(self, store: RecordingStore, events: EventStore | None = None) -> None:
        """``events``: the event log, for a trace to say what the service stored of a message."""
        self._store = store
        self._events = events

    async def types(self) -> list[str]:
        return await self._store.recorded_types()

    async def type_views(self) -> list[TypeView]:
        """Every recorded type: how much of it, from when to when, its field indexes."""
        return [
            TypeView(await self._store.type_summary(name), await self._store.field_indexes(name))
            for name in await self._store.recorded_types()
        ]

    def conditions(self, texts: Sequence[str], type: str) -> list[Condition]:
        """``FIELD OP VALUE`` conditions on ``type``'s fields."""
        with _refused():
            return [parse_condition(text, type) for text in texts]

    async def find(
        self,
        type: str,
        conditions: Sequence[Condition] = (),
        *,
        robot_id: str | None = None,
        mission_id: str | None = None,
        since: datetime | None = None,
        until: datetime | None = None,
        limit: int | None = None,
        newest_first: bool = False,
    ) -> list[RecordedMessage]:
        """Records of ``type`` meeting every condition, in the window; a robot's name that no robot
        can have is refused (an empty answer would look like a robot that sent nothing)."""
        if robot_id is not None:
            try:
                validate_name(robot_id)
            except ValueError as error:
                raise BadRequest(f"robot: {error}") from None
        with _refused():
            return await find(
                self._store,
                type,
                conditions,
                robot_id=robot_id,
                mission_id=mission_id,
                since=since,
                until=until,
                limit=limit,
                newest_first=newest_first,
            )

    async def timeline(
        self,
        robot_id: str,
        since: datetime | None,
        until: datetime | None,
        inbound: Sequence[str] = (),
        limit: int = 1000,
    ) -> Timeline:
        """What ``robot_id`` sent and was sent in the window (``inbound``: its inbox's bindings)."""
        return await timeline(self._store, robot_id, since, until, inbound=inbound, limit=limit)

    async def trace(self, message_id: str, route_map: RouteMap | None = None) -> Trace:
        """All that is known of ``message_id``: its records, what the service stored of it (with the
        event log), what it caused, and the routes of ``route_map``, the broker's now."""
        return await trace(self._store, message_id, events=self._events, route_map=route_map)

    async def evaluate(
        self,
        since: datetime | None = None,
        until: datetime | None = None,
        *,
        robot_id: str | None = None,
        type: str = BEHAVIOUR,
        fields: tuple[str, str, str] = ("name", "success", "duration_s"),
    ) -> list[OutcomeStats]:
        """Per behaviour (the name in ``type``'s first of ``fields``): successes, failures, mean and
        deviation of the duration; ``fields``: the name, success and duration fields."""
        with _refused():
            outcome = OutcomeFields(*(resolve_path(type, name) for name in fields))
            return await evaluate(self._store, since, until, robot_id=robot_id, type=type, fields=outcome)

    async def growth(self, since: datetime | None, every: timedelta) -> list[Growth]:
        """The recording's growth and inserts since ``since``, one row per ``every``."""
        return growth(await self._store.samples(since), every)

    async def samples(self, since: datetime) -> list[StorageSample]:
        """The recorders' samples of the database's size since ``since``."""
        return await self._store.samples(since)

    async def between(
        self,
        since: datetime | None,
        until: datetime | None,
        *,
        types: Sequence[str] = (),
        robot_id: str | None = None,
        conditions: Sequence[Condition] = (),
    ) -> AsyncIterator[RecordedMessage]:
        """The window's records in recording order, streamed (of ``types``, default: all but the
        copies; ``conditions`` need exactly one type)."""
        with _refused():
            async for record in recorded_between(
                self._store, since, until, types=types, robot_id=robot_id, conditions=conditions
            ):
                yield record

    async def ros_schemas(self, selection: Selection) -> dict[str, RosSchema]:
        """The definitions of the recorded ROS types, by key, for an export of ``selection``;
        refused for a robot that has nothing recorded."""
        with _refused():
            types = await self._store.recorded_types()
            for robot in selection.robots:
                for type in types:
                    if await self._store.find_recorded(RecordQuery(type, robot_id=robot, limit=1)):
                        break
                else:
                    raise BadRequest(f"nothing is recorded of robot {robot!r}: no such robot here")
            schemas: dict[str, RosSchema] = {}
            if ROS_SCHEMA_TYPE in types:
                for record in await self._store.find_recorded(RecordQuery(ROS_SCHEMA_TYPE)):
                    schema = RosSchema.of(record.document)
                    if schema is not None:
                        schemas[schema.key] = schema
            return schemas

    async def selected(self, selection: Selection) -> AsyncIterator[RecordedMessage]:
        """The records ``selection`` keeps, in recording order, each with its blobs, streamed."""
        since, until = selection.store_window()
        one = selection.robots[0] if len(selection.robots) == 1 else None
        async for record in self.between(since, until, types=selection.chosen_types, robot_id=one):
            if selection.keeps(record):
                with _refused():
                    kept = await with_blobs(record, self._store.get_blob)
                yield kept

    async def import_bag(
        self, path: Path, robot: str, max_bytes: int, progress: Progress, blob_max: int = 0
    ) -> ImportReport:
        """Every message of the bag at ``path`` as ``robot``'s, or none (a
        :class:`~fleetbus.workers.recorder.bags.BagError` says why)."""
        return await import_bag_into(self._store, path, robot, max_bytes, progress, blob_max)
