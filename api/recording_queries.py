"""The recording's queries as the HTTP API and the console run them: the recorded types, a search
of one type, a robot's timeline, a message's trace, the evaluation of the behaviours and the
recording's growth, each the plain function of :mod:`fleetbus.workers.recorder.queries` (or
:mod:`~fleetbus.workers.recorder.growth`) on the recording and the event log.

A query that cannot be run (a type or a field name that is not one) raises :class:`RecordingError`
saying why. The records these return are this module's to hand out (:data:`__all__`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta

from fleetbus.broker.routes import RouteMap
from fleetbus.workers.recorder.growth import Growth, growth
from fleetbus.workers.recorder.queries import Timeline, Trace, evaluate, find, timeline, trace
from fleetbus.workers.store.base import EventStore
from fleetbus.workers.store.recordings import (
    Condition,
    OutcomeStats,
    RecordedMessage,
    RecordingError,
    RecordingStore,
    TypeSummary,
)

__all__ = [
    "Growth",
    "OutcomeStats",
    "RecordedMessage",
    "RecordedType",
    "RecordingError",
    "RecordingQueries",
    "Timeline",
    "Trace",
    "TypeSummary",
]


@dataclass(frozen=True)
class RecordedType:
    """A recorded type: how much of it, from when to when, and the fields indexed for its queries."""

    name: str
    summary: TypeSummary
    field_indexes: list[tuple[str, ...]]


class RecordingQueries:
    def __init__(self, recording: RecordingStore, events: EventStore) -> None:
        self._recording = recording
        self._events = events

    async def type_names(self) -> list[str]:
        """The names of the recorded types."""
        return await self._recording.recorded_types()

    async def types(self) -> list[RecordedType]:
        """Every recorded type, with its summary and its field indexes."""
        return [
            RecordedType(
                name, await self._recording.type_summary(name), await self._recording.field_indexes(name)
            )
            for name in await self._recording.recorded_types()
        ]

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
        """Records of ``type`` meeting every condition, in the window (:func:`~.queries.find`)."""
        return await find(
            self._recording,
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
        *,
        inbound: Sequence[str] = (),
        limit: int = 1000,
    ) -> Timeline:
        """What the robot sent and was sent in the window, every type in time order."""
        return await timeline(self._recording, robot_id, since, until, inbound=inbound, limit=limit)

    async def trace(self, message_id: str, route_map: RouteMap | None) -> Trace:
        """All that is known of ``message_id``, with its stored copy; empty when never recorded."""
        return await trace(self._recording, message_id, events=self._events, route_map=route_map)

    async def evaluate(
        self, since: datetime | None, until: datetime | None, robot_id: str | None = None
    ) -> list[OutcomeStats]:
        """Per behaviour: successes, failures, mean and deviation of the duration."""
        return await evaluate(self._recording, since, until, robot_id=robot_id)

    async def growth(self, since: datetime | None, every: timedelta) -> list[Growth]:
        """The recording's growth and inserts since ``since``, one row per ``every``."""
        return growth(await self._recording.samples(since), every)
