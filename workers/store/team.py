"""The team: the robots, their kind, localisation and service, which the hazard gate follows
(:mod:`fleetbus.workers.team`)."""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

from fleetbus.workers.store.port import BOOL, TEXT, TIME, Database, Doc, Range, Schema


@dataclass(frozen=True)
class RobotState:
    name: str
    kind: str | None
    localised: bool
    updated_at: datetime | None
    """When its localisation state was last reported."""
    in_service: bool = True
    """False while an operator has taken it out of service: it neither blocks the hazard gate nor
    receives announcements."""
    service_changed_by: str | None = None
    """Who last took it out of service or put it back, and when (the audit record)."""
    service_changed_at: datetime | None = None
    catch_up: bool = False
    """Put back in service since the hazard service last sent it the open hazards it missed."""


@dataclass(frozen=True)
class Localisation:
    """What a robot reported of its localisation, and when."""

    name: str
    localised: bool
    at: datetime


class TeamStore(abc.ABC):
    @abc.abstractmethod
    async def register_robot(self, name: str, kind: str | None) -> None:
        """Record a robot and its kind (explorer, warden, guide); idempotent."""

    async def set_localised(self, name: str, localised: bool, at: datetime) -> None:
        """Record a robot's localisation state (an unknown robot is recorded without a kind)."""
        await self.set_localisations([Localisation(name, localised, at)])

    @abc.abstractmethod
    async def set_localisations(self, reports: Sequence[Localisation]) -> None:
        """Record robots' localisation states, in order, in one write: a worker's batch of poses
        costs one commit, not one each. A report older than the one kept changes nothing."""

    @abc.abstractmethod
    async def robots(self, kind: str | None = None) -> list[RobotState]: ...

    @abc.abstractmethod
    async def set_in_service(self, name: str, in_service: bool, by: str, at: datetime) -> RobotState | None:
        """Take a robot out of service or put it back, recording who and when; put back, it is
        owed a catch-up (:attr:`RobotState.catch_up`). None: no such robot in the team."""

    @abc.abstractmethod
    async def caught_up(self, name: str) -> None:
        """The hazard service sent ``name`` the open hazards it missed: clear its catch-up."""

    @abc.abstractmethod
    async def remove_robot(self, name: str) -> bool:
        """Take a robot out of the team (its account is removed); False when it was not in it."""


ROBOTS = Schema(
    "robots",
    {
        "name": TEXT,
        "kind": TEXT.maybe,
        "localised": BOOL,
        "updated_at": TIME.maybe,
        "in_service": BOOL,
        "service_changed_by": TEXT.maybe,
        "service_changed_at": TIME.maybe,
        "catch_up": BOOL,
    },
    key=("name",),
)


def new_robot(name: str, kind: str | None = None) -> Doc:
    """A robot as it joins the team: not localised, in service, owed nothing."""
    return {
        "name": name,
        "kind": kind,
        "localised": False,
        "updated_at": None,
        "in_service": True,
        "service_changed_by": None,
        "service_changed_at": None,
        "catch_up": False,
    }


class Robots(TeamStore):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._robots = database.collection(ROBOTS)

    async def register_robot(self, name: str, kind: str | None) -> None:
        await self._robots.put(new_robot(name, kind), overwrite=["kind"])

    async def set_localisations(self, reports: Sequence[Localisation]) -> None:
        if not reports:
            return
        reported = ["localised", "updated_at"]

        async def report() -> None:
            for each in reports:
                robot = {**new_robot(each.name), "localised": each.localised, "updated_at": each.at}
                # an older report than the one kept changes nothing
                if not await self._robots.put(robot, overwrite=reported, where={"updated_at": None}):
                    await self._robots.put(robot, overwrite=reported, where={"updated_at": Range(le=each.at)})

        await self._database.transaction(report, urgent=True)

    async def robots(self, kind: str | None = None) -> list[RobotState]:
        where = {} if kind is None else {"kind": kind}
        return [RobotState(**doc) for doc in await self._robots.find(where, order=["name"])]

    async def set_in_service(self, name: str, in_service: bool, by: str, at: datetime) -> RobotState | None:
        change = {"in_service": in_service, "service_changed_by": by, "service_changed_at": at}

        async def change_service() -> RobotState | None:
            if in_service:  # owed a catch-up only when put back from out of service
                await self._robots.update({"name": name, "in_service": False}, {**change, "catch_up": True})
                await self._robots.update({"name": name}, change)
            else:  # nothing owed while out
                await self._robots.update({"name": name}, {**change, "catch_up": False})
            doc = await self._robots.get(name)
            return RobotState(**doc) if doc else None

        return await self._database.transaction(change_service)

    async def caught_up(self, name: str) -> None:
        await self._database.transaction(
            lambda: self._robots.update({"name": name}, {"catch_up": False}), urgent=True
        )

    async def remove_robot(self, name: str) -> bool:
        return await self._robots.delete({"name": name}) == 1
