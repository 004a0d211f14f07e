"""The beacon discard log on MongoDB, one repository of `mongo_repositories`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from bson import ObjectId
from pymongo import DESCENDING
from pymongo.errors import BulkWriteError

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.discards import Discard, DiscardCount, DiscardLog
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable

DUPLICATE_KEY = 11000


def _document(discard: Discard) -> dict[str, Any]:
    # a message id makes a redelivered discard the same document; without one it is always new
    key = f"{discard.exchange}|{discard.message_id}" if discard.message_id else str(ObjectId())
    return {
        "_id": key,
        "exchange": discard.exchange,
        "routing_key": discard.routing_key,
        "user_id": discard.user_id,
        "message_id": discard.message_id,
        "reason": discard.reason,
        "received_at": discard.received_at,
        "received_at_us": to_micros(discard.received_at),
        "headers": discard.headers,
    }


@translate_unavailable(DiscardLog)
class MongoDiscards(OnMongo, DiscardLog):
    async def record_discards(self, discards: Sequence[Discard]) -> int:
        if not discards:
            return 0
        documents = [_document(discard) for discard in discards]
        try:
            await self._collection("beacon_discards").insert_many(documents, ordered=False)
        except BulkWriteError as error:
            errors = error.details.get("writeErrors", [])
            if any(e.get("code") != DUPLICATE_KEY for e in errors):
                raise
            return len(documents) - len(errors)
        return len(documents)

    async def discard_counts(self) -> list[DiscardCount]:
        pipeline = [
            {"$sort": {"received_at_us": 1}},
            {
                "$group": {
                    "_id": "$exchange",
                    "count": {"$sum": 1},
                    "last_at_us": {"$last": "$received_at_us"},
                    "last_reason": {"$last": "$reason"},
                }
            },
            {"$sort": {"_id": 1}},
        ]
        cursor = await self._collection("beacon_discards").aggregate(pipeline)
        return [
            DiscardCount(doc["_id"], doc["count"], from_micros(doc["last_at_us"]), doc["last_reason"])
            async for doc in cursor
        ]

    async def recent_discards(self, limit: int = 20) -> list[Discard]:
        cursor = self._collection("beacon_discards").find({}).sort("received_at_us", DESCENDING).limit(limit)
        return [
            Discard(
                doc["exchange"],
                doc["routing_key"],
                doc.get("user_id"),
                doc.get("message_id"),
                doc["reason"],
                from_micros(doc["received_at_us"]),
                doc.get("headers", {}),
            )
            async for doc in cursor
        ]
