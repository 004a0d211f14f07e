"""The attempt counts on MongoDB, one repository of `mongo_repositories`."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

from pymongo import ReturnDocument

from fleetbus.workers.store.attempts import AttemptLog
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable


@translate_unavailable(AttemptLog)
class MongoAttempts(OnMongo, AttemptLog):
    async def count_attempt(self, key: str, at: datetime) -> int:
        document = await self._collection("delivery_attempts").find_one_and_update(
            {"_id": key},
            {"$inc": {"attempts": 1}, "$set": {"last_at": at}},
            upsert=True,
            return_document=ReturnDocument.AFTER,
        )
        return int(document["attempts"])

    async def forget_attempts(self, keys: Sequence[str]) -> None:
        if keys:
            await self._collection("delivery_attempts").delete_many({"_id": {"$in": list(keys)}})
