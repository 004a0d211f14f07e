"""What the background pruning asks of the store, and the counts of what every bound removed.

Logs are pruned by time, oldest first, in batches the caller sizes, each its own short write, so
that ingest never waits long for the store. Nothing here names an event's key: the event log is
pruned by the time the store received each event, whatever identifies it.

The counts are what an operator reads (``fleetbus stats``): per bound (``events``, ``overflow``…)
and subject (a type, a queue), how many records or messages it removed, and when it last did.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from fleetbus.workers.store.discards import DISCARDS
from fleetbus.workers.store.event_log import EVENTS
from fleetbus.workers.store.hazards import HAZARDS, OPEN, HazardState, pruned_ids_counter
from fleetbus.workers.store.leases import LEASES
from fleetbus.workers.store.ledger import DUPLICATES, SEQUENCES
from fleetbus.workers.store.port import (
    COUNTERS,
    INTEGER,
    SERIAL,
    TEXT,
    TIME,
    Collection,
    Database,
    In,
    NotIn,
    Range,
    Schema,
    prune_oldest,
)
from fleetbus.workers.store.rejections import REJECTIONS
from fleetbus.workers.store.sites import FORWARDS
from fleetbus.workers.store.statuses import STATUSES


@dataclass(frozen=True)
class BoundCount:
    bound: str
    """What was bounded: ``events``, ``hazards``, ``forwards``, ``duplicates``, ``discards``,
    ``map-versions``, ``map-staging``, ``alerts``, ``overflow``."""
    subject: str
    """Within it: the event type, the robot, the queue and why (``warden1.inbox maxlen``)."""
    count: int
    first_at: datetime
    last_at: datetime

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "first_at": self.first_at.isoformat(), "last_at": self.last_at.isoformat()}


class Housekeeping(abc.ABC):
    """Each ``prune_*`` deletes up to ``limit`` of the oldest records that are older than ``before``
    or beyond the newest ``keep`` (either may be None), and says how many it deleted: the caller
    calls again until fewer than ``limit`` go."""

    @abc.abstractmethod
    async def prune_events(self, type: str, before: datetime | None, keep: int | None, limit: int) -> int:
        """The event log's events of ``type``, by the time the store received them; never the
        event of a hazard not yet cleared."""

    @abc.abstractmethod
    async def prune_cleared_hazards(
        self, before: datetime | None, keep: int | None, limit: int, *, unsent_too: bool = False
    ) -> int:
        """Cleared hazards of the registry, by the time they were cleared; never one that is not
        cleared. A site's hazard whose cleared state central has not confirmed stays, unless
        ``unsent_too`` (this store is not a site's). No id a pruned hazard had is given again."""

    @abc.abstractmethod
    async def prune_forwards(self, before: datetime | None, keep: int | None, limit: int) -> int:
        """Central's log of the events sites forwarded, by when central received each; the sites'
        sums (:meth:`~fleetbus.workers.store.sites.SiteRegistry.summaries`) stay as they are."""

    @abc.abstractmethod
    async def prune_numberings(self, before: datetime | None, keep: int | None, limit: int) -> int:
        """The sequence ledger's numberings (a robot's epoch: its high-water mark and open gaps) not
        observed since ``before``, or beyond the ``keep`` observed last. One kept from before the
        ledger noted when each was observed is taken as observed now, the first time."""

    @abc.abstractmethod
    async def prune_rejections(self, before: datetime | None, keep: int | None, limit: int) -> int:
        """Why each dead letter was refused, by when it was."""

    @abc.abstractmethod
    async def prune_gone_workers(self, before: datetime | None, keep: int | None, limit: int) -> int:
        """The statuses of workers that stopped updating them before ``before`` (or beyond the
        ``keep`` updated last), and the leases that expired before ``before`` (an expired lease is
        as good as none: anyone may take it)."""

    @abc.abstractmethod
    async def prune_duplicates(self, before: datetime | None, keep: int | None, limit: int) -> int: ...

    @abc.abstractmethod
    async def prune_discards(self, before: datetime | None, keep: int | None, limit: int) -> int: ...

    @abc.abstractmethod
    async def count_bounded(self, counts: Mapping[tuple[str, str], int], at: datetime) -> None:
        """Add ``counts`` (by bound and subject) to the running totals, durably."""

    @abc.abstractmethod
    async def bound_counts(self) -> list[BoundCount]:
        """Every total, by bound then subject."""


BOUND_COUNTS = Schema(
    "bound_counts",
    {"bound": TEXT, "subject": TEXT, "count": INTEGER, "first_at": TIME, "last_at": TIME},
    key=("bound", "subject"),
)


class StoreHousekeeping(Housekeeping):
    """Each call is one short unit of work, so a worker's batch waits for at most one of them,
    never for a whole round of pruning."""

    def __init__(self, database: Database) -> None:
        self._database = database
        self._events = database.collection(EVENTS)
        self._hazards = database.collection(HAZARDS)
        self._counters = database.collection(COUNTERS)
        self._duplicates = database.collection(DUPLICATES)
        self._sequences = database.collection(SEQUENCES)
        self._rejections = database.collection(REJECTIONS)
        self._statuses = database.collection(STATUSES)
        self._leases = database.collection(LEASES)
        self._forwards = database.collection(FORWARDS)
        self._discards = database.collection(DISCARDS)
        self._counts = database.collection(BOUND_COUNTS)

    async def prune_events(self, type: str, before: datetime | None, keep: int | None, limit: int) -> int:
        async def prune() -> int:
            cut = await _cut(self._events, {"type": type}, "received_at", before, keep)
            if cut is None:
                return 0
            where: dict[str, Any] = {"type": type, "received_at": Range(lt=cut)}
            if type == "hazard":  # the event of a hazard not yet cleared stays
                open_ones = await self._hazards.find({"state": In(OPEN)}, fields=["event"])
                where["message_id"] = NotIn([doc["event"]["message_id"] for doc in open_ones])
            return await self._events.delete(where, order=["received_at"], limit=limit)

        return await self._database.transaction(prune)

    async def prune_cleared_hazards(
        self, before: datetime | None, keep: int | None, limit: int, *, unsent_too: bool = False
    ) -> int:
        cleared = HazardState.CLEARED.value

        async def prune() -> int:
            cut = await _cut(self._hazards, {"state": cleared}, "cleared_at", before, keep)
            if cut is None:
                return 0
            where: dict[str, Any] = {"state": cleared, "cleared_at": Range(lt=cut)}
            if not unsent_too:
                where["unsent"] = False
            doomed = await self._hazards.find(
                where, order=["cleared_at"], limit=limit, fields=["mission_id", "hazard_id"]
            )
            missions: dict[str, list[int]] = {}
            for doc in doomed:
                missions.setdefault(doc["mission_id"], []).append(doc["hazard_id"])
            for mission_id, ids in missions.items():
                highest = max(ids)  # noted first: the next hazard of the mission is numbered above it
                counter = {"name": pruned_ids_counter(mission_id), "last": highest}
                await self._counters.put(counter, where={"last": Range(lt=highest)})
                await self._hazards.delete({"mission_id": mission_id, "hazard_id": In(ids)})
            return len(doomed)

        return await self._database.transaction(prune)

    async def prune_forwards(self, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self._prune_log(self._forwards, "received_at", before, keep, limit, order="received_at")

    async def prune_numberings(self, before: datetime | None, keep: int | None, limit: int) -> int:
        async def prune() -> int:
            await self._sequences.update({"seen_at": None}, {"seen_at": datetime.now(timezone.utc)})
            return await prune_oldest(self._sequences, "seen_at", before, keep, limit, order="seen_at")

        return await self._database.transaction(prune)

    async def prune_rejections(self, before: datetime | None, keep: int | None, limit: int) -> int:
        rejections = self._rejections
        return await self._prune_log(rejections, "rejected_at", before, keep, limit, order="rejected_at")

    async def prune_gone_workers(self, before: datetime | None, keep: int | None, limit: int) -> int:
        async def prune() -> int:
            gone = await prune_oldest(self._statuses, "updated_at", before, keep, limit, order="updated_at")
            if before is not None and gone < limit:
                expired = {"expires_at": Range(lt=before)}
                gone += await self._leases.delete(expired, order=["expires_at"], limit=limit - gone)
            return gone

        return await self._database.transaction(prune)

    async def prune_duplicates(self, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self._prune_log(self._duplicates, "seen_at", before, keep, limit)

    async def prune_discards(self, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self._prune_log(self._discards, "received_at", before, keep, limit)

    async def _prune_log(
        self,
        log: Collection,
        time: str,
        before: datetime | None,
        keep: int | None,
        limit: int,
        *,
        order: str = SERIAL,
    ) -> int:
        """:func:`prune_oldest` of one log, as one short unit of work."""
        return await self._database.transaction(
            lambda: prune_oldest(log, time, before, keep, limit, order=order)
        )

    async def count_bounded(self, counts: Mapping[tuple[str, str], int], at: datetime) -> None:
        async def count() -> None:
            for (bound, subject), n in counts.items():
                if n:
                    row = {"bound": bound, "subject": subject, "count": n, "first_at": at, "last_at": at}
                    await self._counts.increment(row, "count", overwrite=["last_at"])

        await self._database.transaction(count)

    async def bound_counts(self) -> list[BoundCount]:
        return [BoundCount(**doc) for doc in await self._counts.find(order=["bound", "subject"])]


async def _cut(
    log: Collection, where: dict[str, Any], time: str, before: datetime | None, keep: int | None
) -> datetime | None:
    """What goes of ``where``'s documents: those whose ``time`` is before the returned time,
    ``before`` or the oldest of the newest ``keep``, whichever is later (None: nothing goes)."""
    if keep is None:
        return before
    kept = await log.find(where, order=[f"-{time}"], skip=keep - 1, limit=1, fields=[time])
    if not kept:
        return before
    return kept[0][time] if before is None else max(before, kept[0][time])
