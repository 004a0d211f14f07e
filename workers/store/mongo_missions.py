"""Missions on MongoDB, one repository of `mongo_repositories`.

A state change is one ``find_one_and_update`` filtered on the expected state, and the history
entry is pushed in the same update, so the change and its record are one atomic write.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pymongo import ASCENDING, ReturnDocument

from fleetbus.schemas.mission_states import MissionState
from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.missions import Mission, MissionConflict, MissionStore, StateChange, mission_id_of
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable


def _mission(doc: dict[str, Any]) -> Mission:
    return Mission(
        mission_id=doc["_id"],
        number=doc["number"],
        use_case=doc["use_case"],
        title=doc["title"],
        owner=doc["owner"],
        state=MissionState(doc["state"]),
        plan=doc["plan"],
        created_at=from_micros(doc["created_at_us"]),
        updated_at=from_micros(doc["updated_at_us"]),
    )


def _history_entry(
    source: MissionState | None, target: MissionState, by: str, at: datetime, note: str
) -> dict[str, Any]:
    return {
        "source": source.value if source else None,
        "target": target.value,
        "by": by,
        "at_us": to_micros(at),
        "note": note,
    }


@translate_unavailable(MissionStore)
class MongoMissions(OnMongo, MissionStore):
    async def create_mission_indexes(self) -> None:
        missions = self._collection("missions")
        await missions.create_index([("number", ASCENDING)], unique=True)
        await missions.create_index([("owner", ASCENDING), ("number", ASCENDING)])

    async def create_mission(
        self, use_case: str, title: str, owner: str, plan: dict[str, Any], at: datetime
    ) -> Mission:
        counter = await self._collection("counters").find_one_and_update(
            {"_id": "missions"}, {"$inc": {"last": 1}}, upsert=True, return_document=ReturnDocument.AFTER
        )
        number = counter["last"]
        doc = {
            "_id": mission_id_of(number),
            "number": number,
            "use_case": use_case,
            "title": title,
            "owner": owner,
            "state": MissionState.PLANNING.value,
            "plan": plan,
            "created_at_us": to_micros(at),
            "updated_at_us": to_micros(at),
            "history": [_history_entry(None, MissionState.PLANNING, owner, at, "created")],
        }
        await self._collection("missions").insert_one(doc)
        return _mission(doc)

    async def put_mission(self, mission: Mission) -> bool:
        missions = self._collection("missions")
        updated = to_micros(mission.updated_at)
        current = await missions.find_one({"_id": mission.mission_id}, {"history": 0})
        if current is not None and current["updated_at_us"] >= updated:
            return False
        fields = {
            "number": mission.number,
            "use_case": mission.use_case,
            "title": mission.title,
            "owner": mission.owner,
            "state": mission.state.value,
            "plan": mission.plan,
            "created_at_us": to_micros(mission.created_at),
            "updated_at_us": updated,
        }
        update: dict[str, Any] = {"$set": fields}
        if current is None or current["state"] != mission.state.value:
            source = MissionState(current["state"]) if current else None
            entry = _history_entry(source, mission.state, "central", mission.updated_at, "from central")
            update["$push"] = {"history": entry}
        # conditional on the version seen: a newer one written meanwhile is never overwritten
        condition: dict[str, Any] = {"_id": mission.mission_id}
        if current is not None:
            condition["updated_at_us"] = current["updated_at_us"]
        result = await missions.update_one(condition, update, upsert=current is None)
        return result.modified_count > 0 or result.upserted_id is not None

    async def get_mission(self, mission_id: str) -> Mission | None:
        doc = await self._collection("missions").find_one({"_id": mission_id}, {"history": 0})
        return _mission(doc) if doc else None

    async def missions(self, owner: str | None = None, state: MissionState | None = None) -> list[Mission]:
        query: dict[str, Any] = {}
        if owner is not None:
            query["owner"] = owner
        if state is not None:
            query["state"] = state.value
        cursor = self._collection("missions").find(query, {"history": 0}).sort("number", ASCENDING)
        return [_mission(doc) async for doc in cursor]

    async def _conditional(
        self, mission_id: str, condition: dict[str, Any], update: dict[str, Any]
    ) -> Mission:
        doc = await self._collection("missions").find_one_and_update(
            {"_id": mission_id, **condition},
            update,
            projection={"history": 0},
            return_document=ReturnDocument.AFTER,
        )
        if doc is None:
            raise MissionConflict(mission_id, await self.get_mission(mission_id))
        return _mission(doc)

    async def update_plan(
        self, mission_id: str, plan: dict[str, Any], expected: MissionState, at: datetime
    ) -> Mission:
        return await self._conditional(
            mission_id, {"state": expected.value}, {"$set": {"plan": plan, "updated_at_us": to_micros(at)}}
        )

    async def transition_mission(
        self,
        mission_id: str,
        source: MissionState,
        target: MissionState,
        by: str,
        at: datetime,
        note: str = "",
    ) -> Mission:
        return await self._conditional(
            mission_id,
            {"state": source.value},
            {
                "$set": {"state": target.value, "updated_at_us": to_micros(at)},
                "$push": {"history": _history_entry(source, target, by, at, note)},
            },
        )

    async def mission_history(self, mission_id: str) -> list[StateChange]:
        doc = await self._collection("missions").find_one({"_id": mission_id}, {"history": 1})
        return [
            StateChange(
                mission_id,
                MissionState(entry["source"]) if entry["source"] else None,
                MissionState(entry["target"]),
                entry["by"],
                from_micros(entry["at_us"]),
                entry["note"],
            )
            for entry in (doc or {}).get("history", [])
        ]
