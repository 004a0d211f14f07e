"""Central's sites on MongoDB, one repository of `mongo_repositories`."""

from __future__ import annotations

from collections.abc import Collection, Sequence
from datetime import datetime, timezone
from typing import Any

from pymongo import UpdateOne
from pymongo.errors import DuplicateKeyError

from fleetbus.schemas.site_reports import SiteReport
from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable
from fleetbus.workers.store.sites import Forward, SiteRegistry, SiteSummary


def _forward(doc: dict[str, Any]) -> Forward:
    return Forward(
        doc["robot_id"],
        doc["epoch"],
        doc["seq"],
        doc["site"],
        doc["type"],
        from_micros(doc["sent_at_us"]),
        from_micros(doc["received_at_us"]),
        doc["late"],
    )


@translate_unavailable(SiteRegistry)
class MongoSites(OnMongo, SiteRegistry):
    async def set_robots(self, site: str, robots: Collection[str]) -> None:
        await self._collection("sites").update_one(
            {"_id": site}, {"$setOnInsert": {"added_at": datetime.now(timezone.utc)}}, upsert=True
        )
        members = self._collection("site_robots")
        await members.delete_many({"site": site, "_id": {"$nin": list(robots)}})
        for robot in robots:
            await members.replace_one({"_id": robot}, {"site": site}, upsert=True)

    async def remove_site(self, site: str) -> None:
        await self._collection("site_robots").delete_many({"site": site})
        await self._collection("sites").delete_one({"_id": site})

    async def sites(self) -> dict[str, tuple[str, ...]]:
        result: dict[str, list[str]] = {d["_id"]: [] async for d in self._collection("sites").find()}
        async for doc in self._collection("site_robots").find().sort("_id", 1):
            result.setdefault(doc["site"], []).append(doc["_id"])
        return {name: tuple(result[name]) for name in sorted(result)}

    async def site_of(self, robots: Collection[str]) -> dict[str, str]:
        if not robots:
            return {}
        cursor = self._collection("site_robots").find({"_id": {"$in": sorted(set(robots))}})
        return {doc["_id"]: doc["site"] async for doc in cursor}

    async def record_forwards(self, forwards: Sequence[Forward]) -> None:
        if not forwards:
            return
        operations = [
            UpdateOne(
                {"_id": f"{f.robot_id}:{f.epoch}:{f.seq}"},
                {
                    "$setOnInsert": {
                        "robot_id": f.robot_id,
                        "epoch": f.epoch,
                        "seq": f.seq,
                        "site": f.site,
                        "type": f.type,
                        "sent_at": f.sent_at,
                        "sent_at_us": to_micros(f.sent_at),
                        "received_at_us": to_micros(f.received_at),
                        "late": f.late,
                    }
                },
                upsert=True,
            )
            for f in forwards
        ]
        await self._collection("site_forwards").bulk_write(operations, ordered=True)

    async def forwards(self, robot_id: str | None = None) -> list[Forward]:
        query = {} if robot_id is None else {"robot_id": robot_id}
        cursor = self._collection("site_forwards").find(query)
        found = [_forward(doc) async for doc in cursor]
        return sorted(found, key=lambda f: f.key)

    async def summaries(self) -> list[SiteSummary]:
        known = await self.sites()
        pipeline = [
            {"$match": {"site": {"$ne": None}}},
            {
                "$group": {
                    "_id": "$site",
                    "n": {"$sum": 1},
                    "late": {"$sum": {"$cond": ["$late", 1, 0]}},
                    "sent": {"$max": "$sent_at_us"},
                    "received": {"$max": "$received_at_us"},
                }
            },
        ]
        cursor = await self._collection("site_forwards").aggregate(pipeline)
        counts = {doc["_id"]: doc async for doc in cursor}
        summaries = []
        for site, robots in known.items():
            doc = counts.get(site, {})
            summaries.append(
                SiteSummary(
                    site,
                    robots,
                    doc.get("n", 0),
                    doc.get("late", 0),
                    from_micros(doc["sent"]) if doc.get("sent") is not None else None,
                    from_micros(doc["received"]) if doc.get("received") is not None else None,
                )
            )
        return summaries

    async def put_report(self, report: SiteReport) -> bool:
        at = to_micros(report.at)
        reports = self._collection("site_reports")
        doc = {"at_us": at, "report": report.model_dump(mode="json")}
        result = await reports.update_one({"_id": report.site, "at_us": {"$lt": at}}, {"$set": doc})
        if result.matched_count:
            return True
        if await reports.find_one({"_id": report.site}) is not None:
            return False  # one as new or newer is kept
        try:
            await reports.insert_one({"_id": report.site, **doc})
        except DuplicateKeyError:  # another wrote first: keep the newer
            return await self.put_report(report)
        return True

    async def reports(self) -> dict[str, SiteReport]:
        found = {}
        async for doc in self._collection("site_reports").find({}):
            found[doc["_id"]] = SiteReport.model_validate(doc["report"])
        return found
