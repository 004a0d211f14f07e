"""Mounts, check-ins and the channel change log on MongoDB, one repository of `mongo_repositories`.

Without multi-document transactions, booking rests on unique ``_id`` values: a mount is the
document ``_id = robot`` (a second operator's insert fails), and an operator's booking is the
document ``_id = operator`` holding its mission, upserted with the mission in the filter, so an
operator booked by another mission makes the upsert collide instead of matching. The booking
lists what holds it (``mount:<robot>``, ``check-in``) and is deleted when nothing does.
"""

from __future__ import annotations

from collections.abc import Collection
from datetime import datetime
from typing import Any

from pymongo import ASCENDING, DESCENDING
from pymongo.errors import DuplicateKeyError

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.channels import Booked, ChannelAction, ChannelChange, ChannelStore, CheckIn, Mount
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable

CHECK_IN_HOLD = "check-in"


def _mount_hold(robot: str) -> str:
    return f"mount:{robot}"


def _mount(doc: dict[str, Any]) -> Mount:
    return Mount(doc["_id"], doc["operator"], doc["mission_id"], from_micros(doc["mounted_at_us"]))


def _check_in(doc: dict[str, Any]) -> CheckIn:
    return CheckIn(doc["_id"], doc["mission_id"], from_micros(doc["checked_in_at_us"]))


@translate_unavailable(ChannelStore)
class MongoChannels(OnMongo, ChannelStore):
    async def create_channel_indexes(self) -> None:
        await self._collection("mounts").create_index([("operator", ASCENDING)])
        await self._collection("channel_changes").create_index(
            [("mission_id", ASCENDING), ("at_us", ASCENDING)]
        )

    async def _book(self, operator: str, mission_id: str, hold: str) -> None:
        bookings = self._collection("bookings")
        for _ in range(3):  # the booking may be deleted between the collision and the look-up
            try:
                await bookings.update_one(
                    {"_id": operator, "mission_id": mission_id}, {"$addToSet": {"holds": hold}}, upsert=True
                )
                return
            except DuplicateKeyError:
                other = await bookings.find_one({"_id": operator})
                if other is not None:
                    raise Booked(f"operator {operator} is booked by mission {other['mission_id']}") from None
        raise Booked(f"operator {operator} is being booked concurrently; try again")

    async def _release(self, operator: str, hold: str) -> None:
        bookings = self._collection("bookings")
        await bookings.update_one({"_id": operator}, {"$pull": {"holds": hold}})
        await bookings.delete_one({"_id": operator, "holds": {"$size": 0}})

    async def mount(self, robot: str, operator: str, mission_id: str, at: datetime) -> Mount:
        mounts = self._collection("mounts")

        async def refuse_or_same() -> Mount:
            existing = await mounts.find_one({"_id": robot})
            if existing is None:
                raise Booked(f"robot {robot} is being mounted concurrently; try again")
            mount = _mount(existing)
            if (mount.operator, mount.mission_id) != (operator, mission_id):
                raise Booked(f"robot {robot} is mounted by {mount.operator} for mission {mount.mission_id}")
            return mount

        if await mounts.find_one({"_id": robot}) is not None:
            return await refuse_or_same()
        await self._book(operator, mission_id, _mount_hold(robot))
        try:
            await mounts.insert_one(
                {"_id": robot, "operator": operator, "mission_id": mission_id, "mounted_at_us": to_micros(at)}
            )
        except DuplicateKeyError:
            try:
                return await refuse_or_same()
            except Booked:
                await self._release(operator, _mount_hold(robot))
                raise
        return Mount(robot, operator, mission_id, at)

    async def unmount(self, robot: str, operator: str | None = None) -> Mount | None:
        condition: dict[str, Any] = {"_id": robot}
        if operator is not None:
            condition["operator"] = operator
        doc = await self._collection("mounts").find_one_and_delete(condition)
        if doc is None:
            return None
        await self._release(doc["operator"], _mount_hold(robot))
        return _mount(doc)

    async def mounts(
        self, operator: str | None = None, mission_id: str | None = None, robot: str | None = None
    ) -> list[Mount]:
        query = {k: v for k, v in (("operator", operator), ("mission_id", mission_id), ("_id", robot)) if v}
        return [_mount(doc) async for doc in self._collection("mounts").find(query).sort("_id", ASCENDING)]

    async def check_in(self, operator: str, mission_id: str, at: datetime) -> CheckIn:
        check_ins = self._collection("check_ins")
        existing = await check_ins.find_one({"_id": operator})
        if existing is not None and existing["mission_id"] == mission_id:
            return _check_in(existing)
        await self._book(operator, mission_id, CHECK_IN_HOLD)
        try:
            await check_ins.insert_one(
                {"_id": operator, "mission_id": mission_id, "checked_in_at_us": to_micros(at)}
            )
        except DuplicateKeyError:
            existing = await check_ins.find_one({"_id": operator})
            if existing is not None and existing["mission_id"] == mission_id:
                return _check_in(existing)
            raise Booked(f"operator {operator} is checked in to another mission") from None
        return CheckIn(operator, mission_id, at)

    async def check_out(self, operator: str, mission_id: str) -> bool:
        result = await self._collection("check_ins").delete_one({"_id": operator, "mission_id": mission_id})
        if result.deleted_count == 0:
            return False
        await self._release(operator, CHECK_IN_HOLD)
        return True

    async def check_ins(self, mission_id: str | None = None, operator: str | None = None) -> list[CheckIn]:
        query = {k: v for k, v in (("mission_id", mission_id), ("_id", operator)) if v}
        return [
            _check_in(doc) async for doc in self._collection("check_ins").find(query).sort("_id", ASCENDING)
        ]

    async def recording_missions(self, robots: Collection[str]) -> dict[str, str]:
        names = sorted(set(robots))
        if not names:
            return {}
        mounts = [_mount(doc) async for doc in self._collection("mounts").find({"_id": {"$in": names}})]
        if not mounts:
            return {}
        operators = sorted({mount.operator for mount in mounts})
        checked_in = {
            (doc["_id"], doc["mission_id"])
            async for doc in self._collection("check_ins").find({"_id": {"$in": operators}})
        }
        return {m.robot: m.mission_id for m in mounts if (m.operator, m.mission_id) in checked_in}

    async def record_change(self, change: ChannelChange) -> None:
        await self._collection("channel_changes").insert_one(
            {
                "at": change.at,
                "at_us": to_micros(change.at),
                "actor": change.actor,
                "action": change.action.value,
                "mission_id": change.mission_id,
                "operator": change.operator,
                "robot": change.robot,
                "detail": change.detail,
            }
        )

    async def channel_changes(
        self, mission_id: str | None = None, limit: int | None = None
    ) -> list[ChannelChange]:
        query = {"mission_id": mission_id} if mission_id else {}
        cursor = (
            self._collection("channel_changes").find(query).sort([("at_us", DESCENDING), ("_id", DESCENDING)])
        )
        if limit is not None:
            cursor = cursor.limit(limit)
        docs = [doc async for doc in cursor]
        return [
            ChannelChange(
                from_micros(doc["at_us"]),
                doc["actor"],
                ChannelAction(doc["action"]),
                doc.get("mission_id"),
                doc.get("operator"),
                doc.get("robot"),
                doc.get("detail", ""),
            )
            for doc in reversed(docs)
        ]
