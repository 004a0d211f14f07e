"""The production store: MongoDB through pymongo's ``AsyncMongoClient``.

Every repository over one database (:func:`mongo_repositories`). Document ids follow a small
strategy (``<robot>:<epoch>:<seq>``), so MongoDB's own ``_id`` uniqueness makes writes
idempotent. Times are kept twice: as BSON dates for people querying MongoDB, and as integer
microseconds, which round-trip exactly (BSON dates stop at milliseconds).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from pymongo import ASCENDING, DESCENDING
from pymongo.errors import BulkWriteError, PyMongoError

from fleetbus.workers.store.attempts import Attempts
from fleetbus.workers.store.base import (
    EventQuery,
    EventRecord,
    Received,
    StoreUnavailable,
    WriteResult,
    from_micros,
    to_micros,
)
from fleetbus.workers.store.beacons import Beacons
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.interface import StoredBatch, numbers_of, store_in_turn
from fleetbus.workers.store.leases import Leases
from fleetbus.workers.store.mongo_channels import MongoChannels
from fleetbus.workers.store.mongo_coordination import MongoCoordination
from fleetbus.workers.store.mongo_database import (
    DUPLICATE_KEY,
    MongoDatabase,
    raise_as_store_error,
    translate_unavailable,
)
from fleetbus.workers.store.mongo_discards import MongoDiscards
from fleetbus.workers.store.mongo_housekeeping import MongoHousekeeping
from fleetbus.workers.store.mongo_ledger import MongoLedger
from fleetbus.workers.store.mongo_maps import MongoMaps
from fleetbus.workers.store.mongo_missions import MongoMissions
from fleetbus.workers.store.mongo_port import MongoStore
from fleetbus.workers.store.mongo_sites import MongoSites
from fleetbus.workers.store.rejections import Rejections
from fleetbus.workers.store.repositories import EventLog, Repositories
from fleetbus.workers.store.statuses import Statuses
from fleetbus.workers.store.users import Users


class RobotSequenceId:
    """Document-id strategy: one document per (robot, epoch, sequence number)."""

    @staticmethod
    def of(robot_id: str, epoch: str, seq: int) -> str:
        return f"{robot_id}:{epoch}:{seq}"


def to_document(record: EventRecord) -> dict[str, Any]:
    return {
        "_id": RobotSequenceId.of(record.robot_id, record.epoch, record.seq),
        "robot_id": record.robot_id,
        "epoch": record.epoch,
        "seq": record.seq,
        "type": record.type,
        "message_id": record.message_id,
        "sent_at": record.sent_at,
        "sent_at_us": to_micros(record.sent_at),
        "received_at": record.received_at,
        "received_at_us": to_micros(record.received_at),
        "body": record.body,
        "user_id": record.user_id,
        "exchange": record.exchange,
        "routing_key": record.routing_key,
        "mission_id": record.mission_id,
        "digest": record.digest,
    }


def from_document(doc: dict[str, Any]) -> EventRecord:
    return EventRecord(
        robot_id=doc["robot_id"],
        epoch=doc["epoch"],
        seq=doc["seq"],
        type=doc["type"],
        message_id=doc["message_id"],
        sent_at=from_micros(doc["sent_at_us"]),
        received_at=from_micros(doc["received_at_us"]),
        body=doc["body"],
        user_id=doc["user_id"],
        exchange=doc["exchange"],
        routing_key=doc["routing_key"],
        mission_id=doc.get("mission_id"),
        digest=doc.get("digest"),
    )


def mongo_repositories(
    url: str, database: str | None = None, server_selection_timeout: float = 5.0
) -> Repositories:
    """Every repository over one MongoDB database (one client), not yet opened."""
    shared = MongoStore(url, database, server_selection_timeout)
    channels = MongoChannels(shared)
    events = MongoEventLog(shared, channels)
    hazards = MongoCoordination(shared)
    maps = MongoMaps(shared)
    missions = MongoMissions(shared)
    housekeeping = MongoHousekeeping(shared)

    users, rejections, attempts = Users(shared), Rejections(shared), Attempts(shared)
    leases, statuses, beacons = Leases(shared), Statuses(shared), Beacons(shared)

    async def open() -> None:
        await shared.open()
        try:
            await events.create_event_indexes()
            await events.create_ledger_indexes()
            await hazards.create_coordination_indexes()
            await maps.create_map_indexes()
            await housekeeping.create_housekeeping_indexes()
            await missions.create_mission_indexes()
            await channels.create_channel_indexes()
        except PyMongoError as error:
            raise_as_store_error(error, shared._safe_url())

    return Repositories(
        name="mongodb",
        events=events,
        hazards=hazards,
        beacons=beacons,
        maps=maps,
        missions=missions,
        channels=channels,
        users=users,
        discards=MongoDiscards(shared),
        rejections=rejections,
        attempts=attempts,
        leases=leases,
        statuses=statuses,
        housekeeping=housekeeping,
        sites=MongoSites(shared),
        opener=open,
        closer=shared.close,
        again=lambda: mongo_repositories(url, shared._database_name, server_selection_timeout),
    )


def _result(document: dict[str, Any], stored: dict[str, dict[str, Any]]) -> WriteResult:
    """The result of a record not inserted: its key taken, or its number seen and pruned."""
    found = stored.get(document["_id"])
    if found is None:
        return WriteResult(inserted=False, pruned=True)
    same = (found["message_id"], found["received_at_us"]) == (
        document["message_id"],
        document["received_at_us"],
    )
    return WriteResult(
        inserted=False,
        stored_message_id=found["message_id"],
        stored_digest=found.get("digest"),
        rewritten=same,
    )


@translate_unavailable(EventLog)
class MongoEventLog(MongoLedger, EventLog):
    """The event log and its sequence ledger; the system of record for validated events. A batch
    is stamped with the missions the channels record its robots under (:func:`store_in_turn`)."""

    def __init__(self, database: MongoDatabase, channels: ChannelStore) -> None:
        super().__init__(database)
        self._channels = channels

    def _events(self) -> Any:
        """The event log: every validated event, one collection (the recording keeps one per type)."""
        return self._collection("events")

    async def create_event_indexes(self) -> None:
        events = self._events()
        await events.create_index([("type", ASCENDING), ("sent_at_us", ASCENDING)])
        await events.create_index([("robot_id", ASCENDING), ("sent_at_us", ASCENDING)])
        await events.create_index([("sent_at_us", ASCENDING)])
        await events.create_index([("message_id", ASCENDING)])
        await events.create_index([("received_at_us", ASCENDING)])

    async def store_batch(
        self, records: Sequence[EventRecord], at: datetime, *, urgent: bool = False
    ) -> StoredBatch:
        return await store_in_turn(self, self._channels, records, at)

    async def write_events(self, records: Sequence[EventRecord]) -> list[WriteResult]:
        """Insert each record unless its key is taken or the ledger has seen its number (its event
        pruned since)."""
        if not records:
            return []
        seen = await self._observed(numbers_of(records))
        documents = [to_document(record) for record in records]
        taken = {index for index, record in enumerate(records) if record.key in seen}
        fresh = [index for index in range(len(documents)) if index not in taken]
        try:
            if fresh:
                await self._events().insert_many([documents[index] for index in fresh], ordered=False)
        except BulkWriteError as error:
            errors = error.details.get("writeErrors", [])
            if any(e.get("code") != DUPLICATE_KEY for e in errors):
                raise
            if error.details.get("writeConcernErrors"):
                # the documents reached the primary but are not known durable: not safe to ack;
                # a retry is harmless because the ids make it idempotent
                raise StoreUnavailable(
                    f"MongoDB at {self._safe_url()}: write concern not met: "
                    f"{error.details['writeConcernErrors']}"
                ) from error
            # a key repeated inside the batch: MongoDB inserts the first copy and reports the others
            taken.update(fresh[e["index"]] for e in errors)
        except PyMongoError as error:
            raise_as_store_error(error, self._safe_url())
        stored: dict[str, dict[str, Any]] = {}
        if taken:
            try:
                ids = list({documents[index]["_id"] for index in taken})
                fields = ["message_id", "received_at_us", "digest"]
                cursor = self._events().find({"_id": {"$in": ids}}, fields)
                stored = {doc["_id"]: doc async for doc in cursor}
            except PyMongoError as error:
                raise_as_store_error(error, self._safe_url())
        return [
            _result(documents[index], stored) if index in taken else WriteResult(inserted=True)
            for index in range(len(documents))
        ]

    @staticmethod
    def _filter(type: str | None, robot_id: str | None, query: EventQuery | None = None) -> dict[str, Any]:
        conditions: dict[str, Any] = {}
        if type is not None:
            conditions["type"] = type
        if robot_id is not None:
            conditions["robot_id"] = robot_id
        if query is not None and query.mission_id is not None:
            conditions["mission_id"] = query.mission_id
        if query is not None and (query.since or query.until):
            window: dict[str, int] = {}
            if query.since:
                window["$gte"] = to_micros(query.since)
            if query.until:
                window["$lt"] = to_micros(query.until)
            conditions["sent_at_us"] = window
        return conditions

    async def find_events(self, query: EventQuery) -> list[EventRecord]:
        direction = DESCENDING if query.newest_first else ASCENDING
        cursor = (
            self._events()
            .find(self._filter(query.type, query.robot_id, query))
            .sort(
                [("sent_at_us", direction), ("robot_id", direction), ("epoch", direction), ("seq", direction)]
            )
        )
        if query.limit is not None:
            cursor = cursor.limit(query.limit)
        try:
            return [from_document(doc) async for doc in cursor]
        except PyMongoError as error:
            raise_as_store_error(error, self._safe_url())

    def _received_since(self, since: datetime, limit: int, fields: list[str] | None = None) -> Any:
        order = [(name, ASCENDING) for name in ("received_at_us", "robot_id", "epoch", "seq")]
        found = self._events().find({"received_at_us": {"$gte": to_micros(since)}}, fields)
        return found.sort(order).limit(limit)

    async def keys_received_since(self, since: datetime, limit: int) -> list[Received]:
        fields = ["robot_id", "epoch", "seq", "received_at_us"]
        try:
            return [
                Received((doc["robot_id"], doc["epoch"], doc["seq"]), from_micros(doc["received_at_us"]))
                async for doc in self._received_since(since, limit, fields)
            ]
        except PyMongoError as error:
            raise_as_store_error(error, self._safe_url())

    async def events_received_since(self, since: datetime, limit: int) -> list[EventRecord]:
        try:
            return [from_document(doc) async for doc in self._received_since(since, limit)]
        except PyMongoError as error:
            raise_as_store_error(error, self._safe_url())

    async def count_events(self, type: str | None = None, robot_id: str | None = None) -> int:
        try:
            return await self._events().count_documents(self._filter(type, robot_id))
        except PyMongoError as error:
            raise_as_store_error(error, self._safe_url())
