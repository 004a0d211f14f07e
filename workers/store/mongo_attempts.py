"""The attempt counts on MongoDB, mixed into :class:`MongoEventStore`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from datetime import datetime
from typing import Any

from pymongo import ReturnDocument

from fleetbus.workers.store.attempts import AttemptLog


class MongoAttempts(AttemptLog):
    _collection: Callable[[str], Any]

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
