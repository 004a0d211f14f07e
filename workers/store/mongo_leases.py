"""Leases on MongoDB, one repository of `mongo_repositories`.

An acquisition is an upsert on the lease's ``_id`` filtered by "free to take": when someone
else holds a live lease the filter matches nothing, the upsert tries to insert a second document
with the same ``_id``, and the unique index refuses it.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pymongo import ASCENDING
from pymongo.errors import DuplicateKeyError

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.leases import Lease, LeaseStore
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable


@translate_unavailable(LeaseStore)
class MongoLeases(OnMongo, LeaseStore):
    async def acquire_lease(
        self, name: str, holder: str, until: datetime, now: datetime, replacing: str | None = None
    ) -> bool:
        takeable: list[dict[str, Any]] = [{"holder": holder}, {"expires_at_us": {"$lte": to_micros(now)}}]
        if replacing is not None:
            takeable.append({"holder": replacing})
        try:
            await self._collection("leases").update_one(
                {"_id": name, "$or": takeable},
                {"$set": {"holder": holder, "expires_at_us": to_micros(until), "expires_at": until}},
                upsert=True,
            )
        except DuplicateKeyError:
            return False
        return True

    async def release_lease(self, name: str, holder: str) -> None:
        await self._collection("leases").delete_one({"_id": name, "holder": holder})

    async def leases(self, prefix: str = "") -> list[Lease]:
        cursor = self._collection("leases").find({}).sort("_id", ASCENDING)
        return [
            Lease(doc["_id"], doc["holder"], from_micros(doc["expires_at_us"]))
            async for doc in cursor
            if doc["_id"].startswith(prefix)
        ]
