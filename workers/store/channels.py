"""Channel state: which operator has mounted which robot for which mission, who is checked in.

A robot is booked by at most one mount; an operator by at most one mission at a time (its
mounts and its check-in all belong to that mission). Booking is atomic in the store, so of two
operators mounting the same robot one wins. A robot's data is recorded under a mission while
the operator who mounted it for that mission is checked in to it. Every change of these
channels is itself recorded: who did what, to which robot, in which mission, when.
"""

from __future__ import annotations

import abc
from collections.abc import Collection
from dataclasses import dataclass
from datetime import datetime
from enum import Enum

from fleetbus.workers.store.base import StoreError
from fleetbus.workers.store.port import INTEGER, JSON, SERIAL, TEXT, TIME, Database, Doc, In, Index, Schema


class ChannelAction(str, Enum):
    MOUNT = "mount"
    UNMOUNT = "unmount"
    FORCE_UNMOUNT = "force-unmount"
    CHECK_IN = "check-in"
    CHECK_OUT = "check-out"
    REPAIR = "repair"


@dataclass(frozen=True)
class Mount:
    robot: str
    operator: str
    mission_id: str
    mounted_at: datetime


@dataclass(frozen=True)
class CheckIn:
    operator: str
    mission_id: str
    checked_in_at: datetime


@dataclass(frozen=True)
class ChannelChange:
    at: datetime
    actor: str
    action: ChannelAction
    mission_id: str | None
    operator: str | None
    robot: str | None
    detail: str = ""


class Booked(StoreError):
    """The robot or the operator is booked by another mission (or the robot by another operator)."""


class ChannelStore(abc.ABC):
    @abc.abstractmethod
    async def mount(self, robot: str, operator: str, mission_id: str, at: datetime) -> Mount:
        """Book ``robot`` for ``operator`` in the mission; idempotent; raise :class:`Booked`."""

    @abc.abstractmethod
    async def unmount(self, robot: str, operator: str | None = None) -> Mount | None:
        """Remove the robot's mount (only ``operator``'s, when given); the removed mount, or None."""

    @abc.abstractmethod
    async def mounts(
        self, operator: str | None = None, mission_id: str | None = None, robot: str | None = None
    ) -> list[Mount]:
        """Current mounts, by robot."""

    @abc.abstractmethod
    async def check_in(self, operator: str, mission_id: str, at: datetime) -> CheckIn:
        """Check the operator in; idempotent; raise :class:`Booked` if it is booked elsewhere."""

    @abc.abstractmethod
    async def check_out(self, operator: str, mission_id: str) -> bool:
        """Check the operator out of the mission; False when it was not checked in there."""

    @abc.abstractmethod
    async def check_ins(
        self, mission_id: str | None = None, operator: str | None = None
    ) -> list[CheckIn]: ...

    @abc.abstractmethod
    async def recording_missions(self, robots: Collection[str]) -> dict[str, str]:
        """For each of ``robots`` whose data is being recorded now: the mission it is recorded under."""

    @abc.abstractmethod
    async def record_change(self, change: ChannelChange) -> None: ...

    @abc.abstractmethod
    async def channel_changes(
        self, mission_id: str | None = None, limit: int | None = None
    ) -> list[ChannelChange]:
        """Recorded changes, oldest first (the newest ``limit`` when given)."""


MOUNTS = Schema(
    "mounts",
    {"robot": TEXT, "operator": TEXT, "mission_id": TEXT, "mounted_at": TIME},
    key=("robot",),
    indexes=(Index("operator"), Index("mission_id")),
)
CHECK_INS = Schema(
    "check_ins",
    {"operator": TEXT, "mission_id": TEXT, "checked_in_at": TIME},
    key=("operator",),
    indexes=(Index("mission_id"),),
)
BOOKINGS = Schema(
    "bookings",
    {"operator": TEXT, "mission_id": TEXT, "holds": JSON, "version": INTEGER},
    key=("operator",),
)
"""An operator's booking: the one mission its mounts and its check-in belong to, and what holds
it (``mount:<robot>``, ``check-in``); written only as a compare-and-set on its version, and
deleted when nothing holds it. Booking rests on it and on the unique keys of mounts (one per
robot) and check-ins (one per operator), one atomic step each."""
CHANGES = Schema(
    "channel_changes",
    {
        "at": TIME,
        "actor": TEXT,
        "action": TEXT,
        "mission_id": TEXT.maybe,
        "operator": TEXT.maybe,
        "robot": TEXT.maybe,
        "detail": TEXT,
    },
    serial=True,
    indexes=(Index("mission_id", SERIAL),),
)
CHECK_IN_HOLD = "check-in"


def _mount_hold(robot: str) -> str:
    return f"mount:{robot}"


def _change(doc: Doc) -> ChannelChange:
    return ChannelChange(
        doc["at"],
        doc["actor"],
        ChannelAction(doc["action"]),
        doc["mission_id"],
        doc["operator"],
        doc["robot"],
        doc["detail"],
    )


class Channels(ChannelStore):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._mounts = database.collection(MOUNTS)
        self._check_ins = database.collection(CHECK_INS)
        self._bookings = database.collection(BOOKINGS)
        self._changes = database.collection(CHANGES)

    async def _book(self, operator: str, mission_id: str, hold: str) -> None:
        """Add ``hold`` to the operator's booking by ``mission_id``; :class:`Booked` when another
        mission books it."""
        while True:  # each round that fails lost to another writer's change: read again
            booking = await self._bookings.get(operator)
            if booking is None:
                new = {"operator": operator, "mission_id": mission_id, "holds": [hold], "version": 0}
                if (await self._bookings.insert([new]))[0]:
                    return
                continue
            if booking["mission_id"] != mission_id:
                raise Booked(f"operator {operator} is booked by mission {booking['mission_id']}")
            if hold in booking["holds"] or await self._holds(booking, [*booking["holds"], hold]):
                return

    async def _release(self, operator: str, hold: str) -> None:
        while True:
            booking = await self._bookings.get(operator)
            if booking is None or hold not in booking["holds"]:
                return
            if await self._holds(booking, [held for held in booking["holds"] if held != hold]):
                return

    async def _holds(self, booking: Doc, holds: list[str]) -> bool:
        """Write the booking's holds (delete it when none are left) unless it changed since read."""
        read = {"operator": booking["operator"], "version": booking["version"]}
        if not holds:
            return await self._bookings.delete(read) == 1
        return await self._bookings.update(read, {"holds": holds}, add={"version": 1}) == 1

    async def mount(self, robot: str, operator: str, mission_id: str, at: datetime) -> Mount:
        def same_or_refused(found: Doc | None) -> Mount:
            if found is None:
                raise Booked(f"robot {robot} is being mounted concurrently; try again")
            mount = Mount(**found)
            if (mount.operator, mount.mission_id) != (operator, mission_id):
                raise Booked(f"robot {robot} is mounted by {mount.operator} for mission {mount.mission_id}")
            return mount

        async def book() -> Mount:
            found = await self._mounts.get(robot)
            if found is not None:
                return same_or_refused(found)
            await self._book(operator, mission_id, _mount_hold(robot))
            mount = Mount(robot, operator, mission_id, at)
            if (await self._mounts.insert([mount.__dict__]))[0]:
                return mount
            try:
                return same_or_refused(await self._mounts.get(robot))
            except Booked:
                await self._release(operator, _mount_hold(robot))
                raise

        return await self._database.transaction(book)

    async def unmount(self, robot: str, operator: str | None = None) -> Mount | None:
        async def remove() -> Mount | None:
            found = await self._mounts.get(robot)
            if found is None or (operator is not None and found["operator"] != operator):
                return None
            if not await self._mounts.delete(found):
                return None  # another removed it
            await self._release(found["operator"], _mount_hold(robot))
            return Mount(**found)

        return await self._database.transaction(remove)

    async def mounts(
        self, operator: str | None = None, mission_id: str | None = None, robot: str | None = None
    ) -> list[Mount]:
        where = {k: v for k, v in (("operator", operator), ("mission_id", mission_id), ("robot", robot)) if v}
        return [Mount(**doc) for doc in await self._mounts.find(where, order=["robot"])]

    async def check_in(self, operator: str, mission_id: str, at: datetime) -> CheckIn:
        async def book() -> CheckIn:
            found = await self._check_ins.get(operator)
            if found is not None and found["mission_id"] == mission_id:
                return CheckIn(**found)
            await self._book(operator, mission_id, CHECK_IN_HOLD)
            check_in = CheckIn(operator, mission_id, at)
            if (await self._check_ins.insert([check_in.__dict__]))[0]:
                return check_in
            found = await self._check_ins.get(operator)
            if found is not None and found["mission_id"] == mission_id:
                return CheckIn(**found)
            raise Booked(f"operator {operator} is checked in to another mission")

        return await self._database.transaction(book)

    async def check_out(self, operator: str, mission_id: str) -> bool:
        async def leave() -> bool:
            if not await self._check_ins.delete({"operator": operator, "mission_id": mission_id}):
                return False
            await self._release(operator, CHECK_IN_HOLD)
            return True

        return await self._database.transaction(leave)

    async def check_ins(self, mission_id: str | None = None, operator: str | None = None) -> list[CheckIn]:
        where = {k: v for k, v in (("mission_id", mission_id), ("operator", operator)) if v}
        return [CheckIn(**doc) for doc in await self._check_ins.find(where, order=["operator"])]

    async def recording_missions(self, robots: Collection[str]) -> dict[str, str]:
        names = sorted(set(robots))
        if not names:
            return {}

        async def read() -> dict[str, str]:
            mounts = await self._mounts.find({"robot": In(names)})
            if not mounts:
                return {}
            operators = sorted({mount["operator"] for mount in mounts})
            checked_in = {
                (doc["operator"], doc["mission_id"])
                for doc in await self._check_ins.find({"operator": In(operators)})
            }
            return {
                m["robot"]: m["mission_id"] for m in mounts if (m["operator"], m["mission_id"]) in checked_in
            }

        return await self._database.snapshot(read)

    async def record_change(self, change: ChannelChange) -> None:
        await self._changes.insert([{**change.__dict__, "action": change.action.value}])

    async def channel_changes(
        self, mission_id: str | None = None, limit: int | None = None
    ) -> list[ChannelChange]:
        where = {"mission_id": mission_id} if mission_id else {}
        found = await self._changes.find(where, order=["-" + SERIAL], limit=limit)
        return [_change(doc) for doc in reversed(found)]
