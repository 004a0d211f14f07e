"""Missions and their state history.

A state change is a compare-and-set in the store: it names the state it expects to leave, so of
two concurrent changes from the same state exactly one wins and the other learns the state the
winner left behind. Plans can change only while the mission is in planning, checked the same way.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from fleetbus.schemas.mission_states import MissionState
from fleetbus.workers.store.base import StoreError, from_micros, to_micros
from fleetbus.workers.store.port import INTEGER, JSON, TEXT, TIME, Database, Doc, Index, Schema

MISSION_PREFIX = "m-"


def mission_id_of(number: int) -> str:
    return f"{MISSION_PREFIX}{number}"


@dataclass(frozen=True)
class Mission:
    mission_id: str
    number: int
    use_case: str
    title: str
    owner: str
    """The client who requested it."""
    state: MissionState
    plan: dict[str, Any]
    """A :class:`fleetbus.schemas.missions.MissionPlan` as JSON."""
    created_at: datetime
    updated_at: datetime


@dataclass(frozen=True)
class StateChange:
    mission_id: str
    source: MissionState | None
    """``None`` for the creation."""
    target: MissionState
    by: str
    at: datetime
    note: str = ""


class MissionConflict(StoreError):
    """The mission is not in the state the change expected (or does not exist)."""

    def __init__(self, mission_id: str, current: Mission | None) -> None:
        self.current = current
        state = current.state.value if current else None
        super().__init__(
            f"no mission {mission_id!r}" if current is None else f"mission {mission_id} is {state}"
        )


class MissionStore(abc.ABC):
    @abc.abstractmethod
    async def create_mission(
        self, use_case: str, title: str, owner: str, plan: dict[str, Any], at: datetime
    ) -> Mission:
        """A new mission in planning, with the next number (``m-1``, ``m-2``...)."""

    @abc.abstractmethod
    async def get_mission(self, mission_id: str) -> Mission | None: ...

    @abc.abstractmethod
    async def missions(self, owner: str | None = None, state: MissionState | None = None) -> list[Mission]:
        """Missions in creation order."""

    @abc.abstractmethod
    async def update_plan(
        self, mission_id: str, plan: dict[str, Any], expected: MissionState, at: datetime
    ) -> Mission:
        """Replace the plan if the mission is in ``expected``; else raise :class:`MissionConflict`."""

    @abc.abstractmethod
    async def transition_mission(
        self,
        mission_id: str,
        source: MissionState,
        target: MissionState,
        by: str,
        at: datetime,
        note: str = "",
    ) -> Mission:
        """Move from ``source`` to ``target`` atomically and record it; else :class:`MissionConflict`."""

    @abc.abstractmethod
    async def put_mission(self, mission: Mission) -> bool:
        """Keep ``mission`` as another store (central's) has it, unless this store has a version
        as new or newer (by ``updated_at``); whether it was written. Its history here records
        the state it arrived in."""

    @abc.abstractmethod
    async def mission_history(self, mission_id: str) -> list[StateChange]:
        """Every state the mission went through, oldest first."""


MISSIONS = Schema(
    "missions",
    {
        "mission_id": TEXT,
        "number": INTEGER,
        "use_case": TEXT,
        "title": TEXT,
        "owner": TEXT,
        "state": TEXT,
        "plan": JSON,
        "created_at": TIME,
        "updated_at": TIME,
        "history": JSON,
        "version": INTEGER,
    },
    key=("mission_id",),
    indexes=(Index("number", unique=True), Index("owner", "number"), Index("state", "number")),
)
"""A mission keeps its history in its own document, so that a change and its record are one
write; each write is conditional on the version read (a compare-and-set)."""
SUMMARY = [name for name in MISSIONS.fields if name not in ("history", "version")]


def _mission(doc: Doc) -> Mission:
    return Mission(
        **{name: doc[name] for name in SUMMARY if name != "state"}, state=MissionState(doc["state"])
    )


def _entry(change: StateChange) -> dict[str, Any]:
    return {
        "source": change.source.value if change.source else None,
        "target": change.target.value,
        "by": change.by,
        "at": to_micros(change.at),
        "note": change.note,
    }


class Missions(MissionStore):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._missions = database.collection(MISSIONS)

    async def create_mission(
        self, use_case: str, title: str, owner: str, plan: dict[str, Any], at: datetime
    ) -> Mission:
        async def create() -> Mission:
            while True:  # the next number is taken by inserting under it (central's are kept too)
                [last] = await self._missions.find(order=["-number"], limit=1, fields=["number"]) or [
                    {"number": 0}
                ]
                number = last["number"] + 1
                created = StateChange(
                    mission_id_of(number), None, MissionState.PLANNING, owner, at, "created"
                )
                doc = {
                    "mission_id": mission_id_of(number),
                    "number": number,
                    "use_case": use_case,
                    "title": title,
                    "owner": owner,
                    "state": MissionState.PLANNING.value,
                    "plan": plan,
                    "created_at": at,
                    "updated_at": at,
                    "history": [_entry(created)],
                    "version": 0,
                }
                if (await self._missions.insert([doc]))[0]:
                    return _mission(doc)

        return await self._database.transaction(create)

    async def get_mission(self, mission_id: str) -> Mission | None:
        found = await self._missions.find({"mission_id": mission_id}, fields=SUMMARY)
        return _mission(found[0]) if found else None

    async def missions(self, owner: str | None = None, state: MissionState | None = None) -> list[Mission]:
        where = {name: value for name, value in (("owner", owner), ("state", state and state.value)) if value}
        return [_mission(doc) for doc in await self._missions.find(where, order=["number"], fields=SUMMARY)]

    async def update_plan(
        self, mission_id: str, plan: dict[str, Any], expected: MissionState, at: datetime
    ) -> Mission:
        async def update() -> Mission:
            where = {"mission_id": mission_id, "state": expected.value}
            changed = await self._missions.update(where, {"plan": plan, "updated_at": at}, add={"version": 1})
            mission = await self.get_mission(mission_id)
            if not changed or mission is None:
                raise MissionConflict(mission_id, mission)
            return mission

        return await self._database.transaction(update)

    async def transition_mission(
        self,
        mission_id: str,
        source: MissionState,
        target: MissionState,
        by: str,
        at: datetime,
        note: str = "",
    ) -> Mission:
        entry = _entry(StateChange(mission_id, source, target, by, at, note))

        async def transition() -> Mission:
            while True:
                current = await self._missions.get(mission_id)
                if current is None or current["state"] != source.value:
                    raise MissionConflict(mission_id, _mission(current) if current else None)
                changes = {"state": target.value, "updated_at": at, "history": [*current["history"], entry]}
                if await self._changed(current, changes):
                    return _mission({**current, **changes})

        return await self._database.transaction(transition)

    async def _changed(self, current: Doc, changes: dict[str, Any]) -> bool:
        """Write ``changes`` unless another write came after ``current`` was read."""
        where = {"mission_id": current["mission_id"], "version": current["version"]}
        return await self._missions.update(where, changes, add={"version": 1}) == 1

    async def put_mission(self, mission: Mission) -> bool:
        async def put() -> bool:
            while True:
                current = await self._missions.get(mission.mission_id)
                if current is not None and current["updated_at"] >= mission.updated_at:
                    return False
                history = current["history"] if current else []
                if current is None or current["state"] != mission.state.value:
                    source = MissionState(current["state"]) if current else None
                    arrived = StateChange(
                        mission.mission_id,
                        source,
                        mission.state,
                        "central",
                        mission.updated_at,
                        "from central",
                    )
                    history = [*history, _entry(arrived)]
                fields = {**mission.__dict__, "state": mission.state.value, "history": history}
                if current is None:
                    if (await self._missions.insert([{**fields, "version": 0}]))[0]:
                        return True
                elif await self._changed(current, {k: v for k, v in fields.items() if k != "mission_id"}):
                    return True

        return await self._database.transaction(put)

    async def mission_history(self, mission_id: str) -> list[StateChange]:
        found = await self._missions.find({"mission_id": mission_id}, fields=["history"])
        return [
            StateChange(
                mission_id,
                MissionState(entry["source"]) if entry["source"] else None,
                MissionState(entry["target"]),
                entry["by"],
                from_micros(entry["at"]),
                entry["note"],
            )
            for entry in (found[0]["history"] if found else [])
        ]
