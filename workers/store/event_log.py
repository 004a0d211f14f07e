"""The event log and its sequence ledger, over the persistence port: the system of record for
validated events, keyed by robot, epoch and sequence number."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from fleetbus.workers.store.base import EventQuery, EventRecord, Received, WriteResult
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.interface import StoredBatch, held_sequences, numbers_of, stamp_missions
from fleetbus.workers.store.ledger import Ledger
from fleetbus.workers.store.port import (
    BOOL,
    INTEGER,
    JSON,
    TEXT,
    TIME,
    Database,
    Doc,
    Filter,
    Index,
    Range,
    Schema,
)
from fleetbus.workers.store.repositories import EventLog

EVENTS = Schema(
    "events",
    {
        "robot_id": TEXT,
        "epoch": TEXT,
        "seq": INTEGER,
        "type": TEXT,
        "message_id": TEXT,
        "sent_at": TIME,
        "received_at": TIME,
        "body": JSON,
        "user_id": TEXT,
        "exchange": TEXT,
        "routing_key": TEXT,
        "mission_id": TEXT.maybe,
        "digest": TEXT.maybe,
        "redelivered": BOOL.maybe,  # added later: null in events stored before it
    },
    key=("robot_id", "epoch", "seq"),
    indexes=(
        Index("type", "sent_at"),
        Index("robot_id", "sent_at"),
        # each robot's newest of a type (the team's statuses): without it SQLite walks the type's
        # index, every status of the fleet for each robot that sent none
        Index("robot_id", "type", "sent_at"),
        Index("sent_at"),
        Index("message_id"),
        Index("received_at"),
        Index("type", "received_at"),
    ),
)
#: An urgent batch of up to this many events may be written on the caller's thread (``store_batch``).
SMALL_BATCH = 16
#: A bulk batch is written in parts of this many events, letting a waiting urgent call (a hazard's
#: write) in between two parts (:meth:`~fleetbus.workers.store.port.Database.let_urgent_calls_in`).
BULK_PART = 64
KEY = ["robot_id", "epoch", "seq"]


def _record(doc: Doc) -> EventRecord:
    return EventRecord(**{**doc, "redelivered": bool(doc.get("redelivered"))})


def _result(record: EventRecord, stored: Doc | None) -> WriteResult:
    """The result of a record not inserted: its key taken, or its number seen and its event pruned."""
    if stored is None:
        return WriteResult(inserted=False, pruned=True)
    return WriteResult(
        inserted=False,
        stored_message_id=stored["message_id"],
        stored_digest=stored["digest"],
        rewritten=(stored["message_id"], stored["received_at"]) == (record.message_id, record.received_at),
    )


def _where(type: str | None = None, robot_id: str | None = None, query: EventQuery | None = None) -> Filter:
    where: dict[str, Any] = {k: v for k, v in (("type", type), ("robot_id", robot_id)) if v is not None}
    if query is not None and query.mission_id is not None:
        where["mission_id"] = query.mission_id
    if query is not None and (query.since or query.until):
        where["sent_at"] = Range(ge=query.since, lt=query.until)
    return where


class Events(Ledger, EventLog):
    """A batch is stamped with the missions the channels record its robots under, written, and
    observed by the ledger in one unit of work (one transaction on SQLite)."""

    def __init__(self, database: Database, channels: ChannelStore) -> None:
        super().__init__(database)
        self._channels = channels
        self._events = database.collection(EVENTS)

    async def write_events(self, records: Sequence[EventRecord]) -> list[WriteResult]:
        return await self._database.transaction(lambda: self._write(records)) if records else []

    async def _write(self, records: Sequence[EventRecord]) -> list[WriteResult]:
        """Insert each record unless its key is taken or the ledger has seen its number (its event
        pruned since)."""
        seen = await self.observed(numbers_of(records))
        fresh = [index for index, record in enumerate(records) if record.key not in seen]
        inserted = await self._events.insert([records[index].__dict__ for index in fresh])
        written = {index for index, done in zip(fresh, inserted, strict=True) if done}
        taken = [index for index in range(len(records)) if index not in written]
        stored = await self._events.get_many([records[index].key for index in taken])
        results = dict(
            zip(taken, (_result(records[i], doc) for i, doc in zip(taken, stored, strict=True)), strict=True)
        )
        return [results.get(index, WriteResult(inserted=True)) for index in range(len(records))]

    async def store_batch(
        self, records: Sequence[EventRecord], at: datetime, *, urgent: bool = False
    ) -> StoredBatch:
        """One unit of work: the mission lookup, the write and the ledger (on SQLite one commit,
        one fsync). Hazards are registered by the hazard service (``hold_hazards``).

        An urgent small batch is written without the hand-over to SQLite's thread when it can
        be. Bulk batches always take the thread: the event loop keeps receiving while SQLite
        writes, which is what lets the batches grow under load (written on the loop, the drain
        of a backlog fell from about 7,000 to 4,900 events a second in ``python -m bench.ingest``).
        A bulk batch is written :data:`BULK_PART` events at a time, and when an urgent call waits
        (a hazard's write) the parts written are committed first and it goes in between: then the
        batch is more than one transaction, each part whole (after a crash, the redelivered
        batch finds the parts written and stores the rest).
        """
        small = urgent and len(records) <= SMALL_BATCH
        step = max(1, len(records)) if small else BULK_PART

        async def store() -> StoredBatch:
            stamped: list[EventRecord] = []
            results: list[WriteResult] = []
            for start in range(0, len(records), step):
                if start:
                    await self._database.let_urgent_calls_in()
                part = records[start : start + step]
                missions = await self._channels.recording_missions({record.robot_id for record in part})
                part = stamp_missions(part, missions)
                written = await self._write(part)
                await self.observe(held_sequences(part, written), at)
                stamped += part
                results += written
            return StoredBatch(stamped, results)

        return await self._database.transaction(store, urgent=small)

    async def find_events(self, query: EventQuery) -> list[EventRecord]:
        order = [("-" if query.newest_first else "") + name for name in ("sent_at", *KEY)]
        found = await self._events.find(
            _where(query.type, query.robot_id, query), order=order, limit=query.limit
        )
        return [_record(doc) for doc in found]

    async def newest_events(
        self,
        robots: Sequence[str],
        type: str | None = None,
        *,
        since: datetime | None = None,
        until: datetime | None = None,
    ) -> dict[str, EventRecord]:
        where = _where(type, query=EventQuery(since=since, until=until)) or None
        found = await self._events.first_each("robot_id", robots, order=["-sent_at"], where=where)
        return {robot: _record(doc) for robot, doc in found.items()}

    async def keys_received_since(self, since: datetime, limit: int) -> list[Received]:
        # only what the received_at index holds (on SQLite it covers the query)
        found = await self._events.find(
            {"received_at": Range(ge=since)},
            order=["received_at", *KEY],
            limit=limit,
            fields=[*KEY, "received_at"],
        )
        return [Received((doc["robot_id"], doc["epoch"], doc["seq"]), doc["received_at"]) for doc in found]

    async def events_received_since(self, since: datetime, limit: int) -> list[EventRecord]:
        found = await self._events.find(
            {"received_at": Range(ge=since)}, order=["received_at", *KEY], limit=limit
        )
        return [_record(doc) for doc in found]

    async def holds_more_events(self, query: EventQuery, than: int) -> bool:
        where = _where(query.type, query.robot_id, query)
        found = await self._events.find(where, order=["sent_at"], skip=than, limit=1, fields=["sent_at"])
        return bool(found)

    async def count_events(self, type: str | None = None, robot_id: str | None = None) -> int:
        return await self._events.count(_where(type, robot_id))
