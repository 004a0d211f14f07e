"""The workers' statuses on MongoDB, one repository of `mongo_repositories`."""

from __future__ import annotations

from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable
from fleetbus.workers.store.statuses import StatusBoard, WorkerStatus


@translate_unavailable(StatusBoard)
class MongoStatuses(OnMongo, StatusBoard):
    async def put_status(self, status: WorkerStatus) -> None:
        document = {**status.__dict__}
        document.pop("name")
        await self._collection("worker_status").replace_one({"_id": status.name}, document, upsert=True)

    async def statuses(self) -> list[WorkerStatus]:
        cursor = self._collection("worker_status").find().sort("_id", 1)
        return [WorkerStatus(name=d.pop("_id"), **d) async for d in cursor]
