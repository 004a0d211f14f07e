"""The team the hazard gate follows, as the HTTP API shows and changes it (:mod:`fleetbus.workers.team`)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

from fleetbus.api.services.errors import BadRequest, NotFound, Unavailable
from fleetbus.broker.team_changes import HazardServiceNotTold
from fleetbus.schemas.roles import UserRole
from fleetbus.settings import Settings
from fleetbus.workers.store.base import EventStore
from fleetbus.workers.store.team import RobotState, TeamStore
from fleetbus.workers.team import (
    Gate,
    NotAWarden,
    NotInTeam,
    TeamMember,
    change_service,
    gate,
    last_seen_of,
    team_member,
    team_members,
    why_closed,
)

log = logging.getLogger("fleetbus.api.team")

#: Who takes wardens out of service and back: the roles that run missions and their robots.
DISPATCHERS = frozenset({UserRole.SUPERVISOR, UserRole.OPERATOR})


@dataclass(frozen=True)
class TeamView:
    members: list[TeamMember]
    """The page asked for."""
    gate: Gate
    closed_because: str | None
    total: int
    """Robots in the team."""


class Team:
    def __init__(
        self, team: TeamStore, events: EventStore, admin_url: str | None, stale_after: timedelta
    ) -> None:
        """``admin_url``: the broker the hazard service is told of changes through; None for a
        reader that changes nothing."""
        self._team = team
        self._events = events
        self._admin_url = admin_url
        self._stale_after = stale_after

    async def view(
        self, last_seen: Mapping[str, datetime] | None = None, offset: int = 0, limit: int | None = None
    ) -> TeamView:
        """The team (``limit`` robots from ``offset``, by name) and its gate, which counts them all;
        ``last_seen``: when each robot was last heard from, for a caller that keeps it (the console,
        from its live feed), else read from the store (a few queries, however large the team)."""
        now = datetime.now(timezone.utc)
        robots = await self._team.robots()
        page = robots[offset : None if limit is None else offset + limit]
        state = gate(robots)
        if last_seen is None:
            members = await team_members(page, self._events, now, self._stale_after)
            seen = await last_seen_of(self._events, state.waiting_for)
        else:
            stale_after = self._stale_after
            members = [team_member(robot, last_seen.get(robot.name), now, stale_after) for robot in page]
            seen = dict(last_seen)
        return TeamView(members, state, why_closed(state, seen, now), len(robots))

    async def robot(self, name: str) -> RobotState | None:
        """``name``'s entry in the team (its kind, whether in service), None when not in it."""
        return next((robot for robot in await self._team.robots() if robot.name == name), None)

    async def robots(self) -> list[RobotState]:
        """Every robot of the team, by name, as the hazard gate follows it."""
        return await self._team.robots()

    async def member(self, name: str) -> TeamMember:
        found = next((m for m in (await self.view()).members if m.robot.name == name), None)
        if found is None:
            raise NotFound(f"{name} is not in the team")
        return found

    async def set_in_service(self, name: str, in_service: bool, by: str) -> RobotState:
        """Take a warden out of service or put it back, recorded with ``by``; the hazard service is told."""
        if self._admin_url is None:
            raise RuntimeError("the team was opened without a broker: it cannot change the service")
        try:
            robot = await change_service(self._team, self._admin_url, name, in_service, by)
        except NotInTeam as refused:
            raise NotFound(str(refused)) from None
        except NotAWarden as refused:
            raise BadRequest(str(refused)) from None
        except HazardServiceNotTold as error:
            raise Unavailable(str(error)) from error
        log.info("%s %s by %s", name, "back in service" if in_service else "taken out of service", by)
        return robot


def team_for(settings: Settings, team: TeamStore, events: EventStore, admin_url: str | None) -> Team:
    """The team service on the settings' staleness (``FLEETBUS_STALE_AFTER_S``)."""
    return Team(team, events, admin_url, timedelta(seconds=settings.stale_after_s))
