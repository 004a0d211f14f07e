"""The rejections of dead letters on MongoDB, one repository of `mongo_repositories`."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from pymongo import UpdateOne

from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable
from fleetbus.workers.store.rejections import Rejection, RejectionLog


@translate_unavailable(RejectionLog)
class MongoRejections(OnMongo, RejectionLog):
    async def record_rejections(self, rejections: Sequence[Rejection]) -> None:
        if rejections:
            await self._collection("rejections").bulk_write(
                [
                    UpdateOne(
                        {"_id": r.key},
                        {
                            "$setOnInsert": {
                                "reason": r.reason,
                                "detail": r.detail,
                                "rejected_at": r.rejected_at,
                            }
                        },
                        upsert=True,
                    )
                    for r in rejections
                ],
                ordered=False,
            )

    async def rejections(self, keys: Iterable[str]) -> dict[str, Rejection]:
        wanted = list(dict.fromkeys(keys))
        if not wanted:
            return {}
        cursor = self._collection("rejections").find({"_id": {"$in": wanted}})
        return {
            d["_id"]: Rejection(d["_id"], d["reason"], d["detail"], d["rejected_at"]) async for d in cursor
        }
