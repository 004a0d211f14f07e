"""The coordination (hazards and team) repository on MongoDB."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from pymongo import ASCENDING, DESCENDING, ReturnDocument
from pymongo.errors import DuplicateKeyError

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.hazards import (
    MOST_HAZARDS,
    CoordinationStore,
    Hazard,
    HazardState,
    RobotState,
    SiteApplied,
    Transition,
    refuse_transition,
)
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable

TIMES = ("announced_at", "claimed_at", "reached_at", "cleared_at")
#: What a robot's document starts with: in the team, in service, nothing owed.
NEW_ROBOT = {"in_service": True, "service_changed_by": None, "service_changed_at_us": None, "catch_up": False}
#: What every change of a hazard's state adds: a new version, not yet sent to central (at a site).
#: ``unsent`` is False once the version is marked sent; a document made before it had none is unsent.
CHANGED = {"$inc": {"version": 1}, "$set": {"unsent": True}}


def hazard_id_of(mission_id: str, hazard_id: int) -> str:
    return f"{mission_id}:{hazard_id}"


def _hazard(doc: dict[str, Any]) -> Hazard:
    return Hazard(
        mission_id=doc["mission_id"],
        hazard_id=doc["hazard_id"],
        robot_id=doc["robot_id"],
        epoch=doc["epoch"],
        seq=doc["seq"],
        event=doc["event"],
        state=HazardState(doc["state"]),
        received_at=from_micros(doc["received_at_us"]),
        claimed_by=doc.get("claimed_by"),
        held_reason=doc.get("held_reason"),
        version=doc.get("version", 0),
        site=doc.get("site"),
        site_hazard_id=doc.get("site_hazard_id"),
        **{
            name: from_micros(doc[f"{name}_us"]) if doc.get(f"{name}_us") is not None else None
            for name in TIMES
        },
    )


def _robot(doc: dict[str, Any]) -> RobotState:
    def moment(name: str) -> datetime | None:
        stamp = doc.get(name)
        return from_micros(stamp) if stamp else None

    return RobotState(
        doc["_id"],
        doc.get("kind"),
        bool(doc.get("localised")),
        moment("updated_at_us"),
        in_service=doc.get("in_service", True),
        service_changed_by=doc.get("service_changed_by"),
        service_changed_at=moment("service_changed_at_us"),
        catch_up=bool(doc.get("catch_up")),
    )


@translate_unavailable(CoordinationStore)
class MongoCoordination(OnMongo, CoordinationStore):
    async def create_coordination_indexes(self) -> None:
        await self._collection("hazards").create_index(
            [("robot_id", ASCENDING), ("epoch", ASCENDING), ("seq", ASCENDING)], unique=True
        )
        await self._collection("hazards").create_index(
            [("state", ASCENDING), ("mission_id", ASCENDING), ("hazard_id", ASCENDING)]
        )
        await self._collection("hazards").create_index([("mission_id", ASCENDING), ("hazard_id", ASCENDING)])
        await self._collection("hazards").create_index(
            [("announced_at_us", ASCENDING), ("mission_id", ASCENDING), ("hazard_id", ASCENDING)]
        )
        await self._collection("hazards").create_index([("received_at_us", DESCENDING)])
        await self._collection("hazards").create_index([("unsent", ASCENDING), ("site", ASCENDING)])
        await self._collection("hazards").create_index([("state", ASCENDING), ("received_at_us", DESCENDING)])

    async def register_robot(self, name: str, kind: str | None) -> None:
        await self._collection("robots").update_one(
            {"_id": name},
            {
                "$set": {"kind": kind},
                "$setOnInsert": {"localised": False, "updated_at_us": None, **NEW_ROBOT},
            },
            upsert=True,
        )

    async def set_localised(self, name: str, localised: bool, at: datetime) -> None:
        stamp = to_micros(at)
        robots = self._collection("robots")
        current = await robots.find_one({"_id": name})
        if current is None:
            try:
                await robots.insert_one(
                    {"_id": name, "kind": None, "localised": localised, "updated_at_us": stamp, **NEW_ROBOT}
                )
                return
            except DuplicateKeyError:
                pass
        older = {"$or": [{"updated_at_us": None}, {"updated_at_us": {"$lte": stamp}}]}
        await robots.update_one(
            {"_id": name, **older}, {"$set": {"localised": localised, "updated_at_us": stamp}}
        )

    async def robots(self, kind: str | None = None) -> list[RobotState]:
        query = {} if kind is None else {"kind": kind}
        return [_robot(doc) async for doc in self._collection("robots").find(query).sort("_id", ASCENDING)]

    async def set_in_service(self, name: str, in_service: bool, by: str, at: datetime) -> RobotState | None:
        change: dict[str, Any] = {
            "in_service": in_service,
            "service_changed_by": by,
            "service_changed_at_us": to_micros(at),
        }
        robots = self._collection("robots")
        if not in_service:
            doc = await robots.find_one_and_update(
                {"_id": name}, {"$set": {**change, "catch_up": False}}, return_document=ReturnDocument.AFTER
            )
            return _robot(doc) if doc else None
        # owed a catch-up only when put back from out of service (one atomic update each way)
        await robots.update_one({"_id": name, "in_service": False}, {"$set": {**change, "catch_up": True}})
        doc = await robots.find_one_and_update(
            {"_id": name}, {"$set": change}, return_document=ReturnDocument.AFTER
        )
        return _robot(doc) if doc else None

    async def caught_up(self, name: str) -> None:
        await self._collection("robots").update_one({"_id": name}, {"$set": {"catch_up": False}})

    async def remove_robot(self, name: str) -> bool:
        result = await self._collection("robots").delete_one({"_id": name})
        return bool(result.deleted_count)

    async def add_hazard(
        self,
        mission_id: str,
        robot_id: str,
        epoch: str,
        seq: int,
        event: dict[str, Any],
        received_at: datetime,
        held: bool,
    ) -> Hazard:
        hazards = self._collection("hazards")
        source = {"robot_id": robot_id, "epoch": epoch, "seq": seq}
        while True:
            existing = await hazards.find_one(source)
            if existing:
                return _hazard(existing)
            # the next id is taken by inserting the hazard under it: one write, so a worker that
            # dies between choosing and writing leaves no id unused (a counter would skip one)
            last = await hazards.find_one({"mission_id": mission_id}, sort=[("hazard_id", DESCENDING)])
            next_id = (last["hazard_id"] if last else 0) + 1
            doc = {
                "_id": hazard_id_of(mission_id, next_id),
                "mission_id": mission_id,
                "hazard_id": next_id,
                **source,
                "event": event,
                "state": (HazardState.HELD if held else HazardState.ANNOUNCED).value,
                "received_at": received_at,
                "received_at_us": to_micros(received_at),
                "claimed_by": None,
                "held_reason": None,
                **{f"{name}_us": None for name in TIMES},
                "announced_at_us": None if held else to_micros(received_at),
                "version": 0,
                "unsent": True,
            }
            try:
                await hazards.insert_one(doc)
                return _hazard(doc)
            except DuplicateKeyError:  # the id, or this event, taken meanwhile: look again
                continue

    async def held_hazards(self, mission_id: str | None = None) -> list[Hazard]:
        query: dict[str, Any] = {"state": HazardState.HELD.value}
        if mission_id is not None:
            query["mission_id"] = mission_id
        cursor = (
            self._collection("hazards")
            .find(query)
            .sort([("mission_id", ASCENDING), ("hazard_id", ASCENDING)])
        )
        return [_hazard(doc) async for doc in cursor]

    async def unannounced_hazards(self) -> list[Hazard]:
        cursor = (
            self._collection("hazards")
            .find({"announced_at_us": None, "site": None})  # a site's hazards are announced there
            .sort([("mission_id", ASCENDING), ("hazard_id", ASCENDING)])
        )
        return [_hazard(doc) async for doc in cursor]

    async def mark_announced(self, hazards: list[Hazard], at: datetime) -> None:
        ids = [hazard_id_of(h.mission_id, h.hazard_id) for h in hazards]
        collection, stamp = self._collection("hazards"), to_micros(at)
        announced = {"state": HazardState.ANNOUNCED.value, "announced_at_us": stamp, "held_reason": None}
        await collection.update_many(
            {"_id": {"$in": ids}, "state": HazardState.HELD.value},
            {**CHANGED, "$set": {**CHANGED["$set"], **announced}},
        )
        # one claimed by the first warden to get it, before this mark
        await collection.update_many(
            {"_id": {"$in": ids}, "announced_at_us": None},
            {**CHANGED, "$set": {**CHANGED["$set"], "announced_at_us": stamp}},
        )

    async def note_held(self, hazards: list[Hazard], reason: str) -> None:
        ids = [hazard_id_of(h.mission_id, h.hazard_id) for h in hazards]
        await self._collection("hazards").update_many(
            {"_id": {"$in": ids}, "state": HazardState.HELD.value}, {"$set": {"held_reason": reason}}
        )

    async def get_hazard(self, mission_id: str, hazard_id: int) -> Hazard | None:
        doc = await self._collection("hazards").find_one({"_id": hazard_id_of(mission_id, hazard_id)})
        return _hazard(doc) if doc else None

    async def open_hazards(self, mission_id: str | None) -> list[Hazard]:
        query: dict[str, Any] = {"state": {"$ne": HazardState.CLEARED.value}}
        if mission_id is not None:
            query["mission_id"] = mission_id
        cursor = (
            self._collection("hazards")
            .find(query)
            .sort([("mission_id", ASCENDING), ("hazard_id", ASCENDING)])
        )
        return [_hazard(doc) async for doc in cursor]

    async def recent_hazards(
        self, limit: int, offset: int = 0, state: HazardState | None = None
    ) -> list[Hazard]:
        newest_first = [("received_at_us", DESCENDING), ("mission_id", DESCENDING), ("hazard_id", DESCENDING)]
        query = {"state": state.value} if state is not None else {}
        if offset > MOST_HAZARDS:
            return []
        cursor = self._collection("hazards").find(query).sort(newest_first).skip(offset).limit(limit)
        return [_hazard(doc) async for doc in cursor]

    async def hazard_counts(self) -> dict[HazardState, int]:
        by_state = [{"$group": {"_id": "$state", "n": {"$sum": 1}}}]
        cursor = await self._collection("hazards").aggregate(by_state)
        return {HazardState(doc["_id"]): doc["n"] async for doc in cursor}

    async def cleared_hazards(self, limit: int) -> list[Hazard]:
        cursor = (
            self._collection("hazards")
            .find({"state": HazardState.CLEARED.value})
            .sort([("cleared_at_us", DESCENDING), ("mission_id", ASCENDING), ("hazard_id", ASCENDING)])
            .limit(limit)
        )
        return [_hazard(doc) async for doc in cursor]

    async def unsent_hazards(self, limit: int) -> list[Hazard]:
        cursor = (
            self._collection("hazards")
            .find({"unsent": {"$ne": False}, "site": None})
            .sort([("mission_id", ASCENDING), ("hazard_id", ASCENDING)])
            .limit(limit)
        )
        return [_hazard(doc) async for doc in cursor]

    async def mark_sent(self, hazards: Sequence[Hazard]) -> None:
        collection = self._collection("hazards")
        for hazard in hazards:
            # only the version sent: a change since keeps it unsent (0 is also a document's without one)
            version: dict[str, Any] = {"$in": [0, None]} if hazard.version == 0 else hazard.version
            await collection.update_one(
                {"_id": hazard_id_of(hazard.mission_id, hazard.hazard_id), "version": version},
                {"$set": {"unsent": False}},
            )

    async def apply_site_hazard(self, site: str, hazard: Hazard) -> tuple[SiteApplied, Hazard | None]:
        hazards = self._collection("hazards")
        source = {"robot_id": hazard.robot_id, "epoch": hazard.epoch, "seq": hazard.seq}
        state = {
            "state": hazard.state.value,
            "claimed_by": hazard.claimed_by,
            "held_reason": hazard.held_reason,
            "version": hazard.version,
            "site_hazard_id": hazard.hazard_id,
            **{f"{name}_us": _micros(getattr(hazard, name)) for name in TIMES},
        }
        while True:
            existing = await hazards.find_one(source)
            if existing is None:
                last = await hazards.find_one(
                    {"mission_id": hazard.mission_id}, sort=[("hazard_id", DESCENDING)]
                )
                next_id = (last["hazard_id"] if last else 0) + 1
                doc = {
                    "_id": hazard_id_of(hazard.mission_id, next_id),
                    "mission_id": hazard.mission_id,
                    "hazard_id": next_id,
                    **source,
                    "event": hazard.event,
                    "received_at": hazard.received_at,
                    "received_at_us": to_micros(hazard.received_at),
                    "site": site,
                    "unsent": False,
                    **state,
                }
                try:
                    await hazards.insert_one(doc)
                except DuplicateKeyError:  # the id, or this event, taken meanwhile: look again
                    continue
                return SiteApplied.APPLIED, _hazard(doc)
            if existing.get("site") != site:
                return SiteApplied.NOT_THE_SITES, _hazard(existing)
            doc = await hazards.find_one_and_update(
                {"_id": existing["_id"], "site": site, "version": {"$lt": hazard.version}},
                {"$set": state},
                return_document=ReturnDocument.AFTER,
            )
            if doc is None:
                current = await hazards.find_one({"_id": existing["_id"]})
                return SiteApplied.STALE, _hazard(current) if current else None
            return SiteApplied.APPLIED, _hazard(doc)

    async def apply_transition(
        self, mission_id: str, hazard_id: int, warden: str, transition: Transition, at: datetime
    ) -> Hazard:
        condition: dict[str, Any] = {
            "_id": hazard_id_of(mission_id, hazard_id),
            "state": {"$in": [source.value for source in transition.sources]},
            "site": None,  # a site's hazard takes its steps at its site (its state here is the site's)
        }
        if transition.claimer_only:
            condition["claimed_by"] = warden
        change: dict[str, Any] = {"state": transition.target.value}
        if transition.stamp is None:  # a release gives the claim up
            change.update(claimed_by=None, claimed_at_us=None)
        else:
            change[f"{transition.stamp}_us"] = to_micros(at)
            if not transition.claimer_only:
                change["claimed_by"] = warden
        await self._collection("hazards").find_one_and_update(
            condition, {**CHANGED, "$set": {**CHANGED["$set"], **change}}
        )
        hazard = await self.get_hazard(mission_id, hazard_id)
        if hazard is None or not transition.done_by(hazard, warden):
            raise refuse_transition(hazard, mission_id, hazard_id, transition.action, warden)
        return hazard


def _micros(moment: datetime | None) -> int | None:
    return to_micros(moment) if moment else None
