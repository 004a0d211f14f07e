"""The workers' statuses on MongoDB, mixed into :class:`MongoEventStore`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fleetbus.workers.store.statuses import StatusBoard, WorkerStatus


class MongoStatuses(StatusBoard):
    _collection: Callable[[str], Any]

    async def put_status(self, status: WorkerStatus) -> None:
        document = {**status.__dict__}
        document.pop("name")
        await self._collection("worker_status").replace_one({"_id": status.name}, document, upsert=True)

    async def statuses(self) -> list[WorkerStatus]:
        cursor = self._collection("worker_status").find().sort("_id", 1)
        return [WorkerStatus(name=d.pop("_id"), **d) async for d in cursor]
