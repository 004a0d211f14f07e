"""The stored events as the HTTP API and the console read them: a mission's recorded events for
whoever may see the mission (:class:`MissionEvents`), and the event log's reads behind the
console's live parts (:class:`StoredEvents`: the feed, the newest of each robot, the trails).

The records these return, and the times their ids are made of, are this module's to hand out
(:data:`__all__`): the adapters import them from here, not from the store.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

from fleetbus.api.services.errors import Forbidden
from fleetbus.api.services.missions import Missions
from fleetbus.schemas.roles import MISSION_DATA_READERS
from fleetbus.workers.store.base import (
    EventQuery,
    EventRecord,
    EventStore,
    Received,
    StoreError,
    from_micros,
    to_micros,
)
from fleetbus.workers.store.ledger import Gap
from fleetbus.workers.store.users import User

__all__ = [
    "EventRecord",
    "Gap",
    "MissionEvents",
    "Received",
    "StoreError",
    "StoredEvents",
    "from_micros",
    "to_micros",
]


class StoredEvents:
    def __init__(self, events: EventStore) -> None:
        self._events = events

    async def newest(
        self, limit: int, type: str | None = None, robot_id: str | None = None
    ) -> list[EventRecord]:
        """The newest ``limit`` events (of ``type``, of ``robot_id`` if given), newest first."""
        return await self._events.find_events(
            EventQuery(type=type, robot_id=robot_id, limit=limit, newest_first=True)
        )

    async def sent_between(
        self, type: str, since: datetime, until: datetime, limit: int
    ) -> list[EventRecord]:
        """The newest ``limit`` events of ``type`` sent in [since, until), newest first."""
        return await self._events.find_events(
            EventQuery(type=type, since=since, until=until, limit=limit, newest_first=True)
        )

    async def more_sent_between(self, type: str, since: datetime, until: datetime, than: int) -> bool:
        """Whether more than ``than`` events of ``type`` were sent in [since, until) (an index read)."""
        return await self._events.holds_more_events(EventQuery(type=type, since=since, until=until), than)

    async def newest_of(
        self,
        robots: Sequence[str],
        type: str | None = None,
        *,
        since: datetime | None = None,
        until: datetime | None = None,
    ) -> dict[str, EventRecord]:
        """Each of ``robots``' newest event (of ``type`` if given; sent in [``since``, ``until``)
        if given), for those that sent one: one query, an index seek for each robot."""
        return await self._events.newest_events(robots, type, since=since, until=until)

    async def received_since(self, since: datetime, limit: int) -> list[EventRecord]:
        """The first ``limit`` events received since ``since``, in the order they were received."""
        return await self._events.events_received_since(since, limit)

    async def keys_received_since(self, since: datetime, limit: int) -> list[Received]:
        """What :meth:`received_since` finds, only the keys and receive times (an index read)."""
        return await self._events.keys_received_since(since, limit)


class MissionEvents:
    """A mission's recorded events, for whoever may see the mission
    (:meth:`~fleetbus.api.services.missions.Missions.get`: a client its own missions)."""

    def __init__(self, missions: Missions, events: EventStore) -> None:
        self._missions = missions
        self._events = events

    async def recorded(
        self,
        user: User,
        mission_id: str,
        type: str | None = None,
        limit: int | None = None,
        newest_first: bool = False,
    ) -> list[EventRecord]:
        """The events recorded under the mission (of ``type`` if given), at most ``limit``; for a
        role of :data:`MISSION_DATA_READERS` only."""
        if user.role not in MISSION_DATA_READERS:
            raise Forbidden(f"a {user.role.value} may not read what was recorded under a mission")
        await self._missions.get(user, mission_id)
        return await self._events.find_events(
            EventQuery(type=type, mission_id=mission_id, limit=limit, newest_first=newest_first)
        )
