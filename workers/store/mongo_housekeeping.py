"""Pruning and the bound counts on MongoDB, one repository of `mongo_repositories`.

A batch is the ids of the oldest prunable documents, then one ``delete_many`` of those ids: the
ids are read back, never made up, so this does not depend on how an event's id is composed.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime
from typing import Any

from pymongo import ASCENDING, DESCENDING

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.hazards import HazardState
from fleetbus.workers.store.housekeeping import BoundCount, Housekeeping
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable


@translate_unavailable(Housekeeping)
class MongoHousekeeping(OnMongo, Housekeeping):
    async def create_housekeeping_indexes(self) -> None:
        await self._collection("events").create_index([("type", ASCENDING), ("received_at_us", ASCENDING)])
        await self._collection("duplicates").create_index([("seen_at_us", ASCENDING)])
        await self._collection("beacon_discards").create_index([("received_at_us", ASCENDING)])

    async def _open_hazard_message_ids(self) -> list[str]:
        cursor = self._collection("hazards").find(
            {"state": {"$ne": HazardState.CLEARED.value}}, {"event.message_id": 1}
        )
        return [doc["event"]["message_id"] async for doc in cursor if doc.get("event", {}).get("message_id")]

    async def prune_events(self, type: str, before: datetime | None, keep: int | None, limit: int) -> int:
        events = self._collection("events")
        cut = to_micros(before) if before is not None else None
        if keep is not None:
            kept = await self._nth_newest(events, {"type": type}, "received_at_us", keep - 1)
            if kept is not None:  # the oldest of the newest ``keep``: everything received before it goes
                cut = kept if cut is None else max(cut, kept)
        if cut is None:
            return 0
        query: dict[str, Any] = {"type": type, "received_at_us": {"$lt": cut}}
        if type == "hazard":
            query["message_id"] = {"$nin": await self._open_hazard_message_ids()}
        return await self._delete_first(events, query, "received_at_us", limit)

    async def prune_duplicates(self, before: datetime | None, keep: int | None, limit: int) -> int:
        # ObjectIds grow with each insert: the store's own order, for the count
        return await self._prune("duplicates", "seen_at_us", "_id", before, keep, limit)

    async def prune_discards(self, before: datetime | None, keep: int | None, limit: int) -> int:
        return await self._prune("beacon_discards", "received_at_us", "received_at_us", before, keep, limit)

    async def _prune(
        self, name: str, time: str, order: str, before: datetime | None, keep: int | None, limit: int
    ) -> int:
        collection = self._collection(name)
        deleted = 0
        if before is not None:
            deleted += await self._delete_first(collection, {time: {"$lt": to_micros(before)}}, time, limit)
        if keep is not None and deleted < limit:
            last = await self._nth_newest(collection, {}, order, keep)
            if last is not None:
                deleted += await self._delete_first(
                    collection, {order: {"$lte": last}}, order, limit - deleted
                )
        return deleted

    @staticmethod
    async def _delete_first(collection: Any, query: dict[str, Any], order: str, limit: int) -> int:
        ids = [
            doc["_id"] async for doc in collection.find(query, {"_id": 1}).sort(order, ASCENDING).limit(limit)
        ]
        return (await collection.delete_many({"_id": {"$in": ids}})).deleted_count if ids else 0

    @staticmethod
    async def _nth_newest(collection: Any, query: dict[str, Any], order: str, skip: int) -> Any:
        """``order``'s value in the document after the newest ``skip`` (0: the newest); None if fewer."""
        cursor = collection.find(query, {order: 1}).sort(order, DESCENDING).skip(skip).limit(1)
        found = [doc[order] async for doc in cursor]
        return found[0] if found else None

    async def count_bounded(self, counts: Mapping[tuple[str, str], int], at: datetime) -> None:
        moment = to_micros(at)
        for (bound, subject), count in counts.items():
            if count:
                await self._collection("bound_counts").update_one(
                    {"_id": f"{bound}|{subject}"},
                    {
                        "$inc": {"count": count},
                        "$set": {"last_at_us": moment},
                        "$setOnInsert": {"bound": bound, "subject": subject, "first_at_us": moment},
                    },
                    upsert=True,
                )

    async def bound_counts(self) -> list[BoundCount]:
        cursor = (
            self._collection("bound_counts").find({}).sort([("bound", ASCENDING), ("subject", ASCENDING)])
        )
        return [
            BoundCount(
                doc["bound"],
                doc["subject"],
                doc["count"],
                from_micros(doc["first_at_us"]),
                from_micros(doc["last_at_us"]),
            )
            async for doc in cursor
        ]
